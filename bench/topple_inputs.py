#!/usr/bin/env python3
"""Two measurements behind the topple head's inputs and the rotation goal (issue 11).

    .venv/bin/python bench/topple_inputs.py [--checkpoint CKPT] [--data data/pybullet_test] [--samplings 50]

1. Descriptor density: a 10 cm cube sampled `--samplings` times with 128 and with 1024 random surface points
   (trimesh, seeds 0..): the distance from its corners to the nearest sampled point, and its tilt barriers toward
   its four faces (support.tilt_barriers) against the exact g a (sqrt(2) - 1). Why inputs version 6 reads 1024.
2. Rotation error split (with --data): the checkpoint's 60-step roll-outs (physdyn evaluate's, learn/evaluate.py
   model_rollouts) on the dataset's test split; over the pushes that do not topple, the final rotation error and
   its yaw (z) and tilt (x, y) parts as a rotation vector in world axes, the true turn, the shapes with the
   largest median error, and by initial spin about z (bins in rad/s) the error and how far the model turns the
   object about z against how far it turns (median of the ratio; over 180° the angles wrap).
Prints both; the last line is one JSON object: corner_gap_cm {128, 1024}, barrier_ratio {128, 1024} (median and
p90 of |barrier / exact - 1|), and with --data rotation {n, error_median_deg, yaw_median_deg, tilt_median_deg,
true_turn_median_deg, worst: {shape: median deg}, by_spin: {bin: {n, error_median_deg, turn_ratio_median}}}.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
#: rad/s, initial |w_z| bins of the rotation split
SPIN_BINS = ((0.0, 0.5), (0.5, 2.0), (2.0, 6.0), (6.0, float("inf")))


def density(samplings: int) -> dict:
    import trimesh

    from physdyn_ros.conventions import GRAVITY
    from physdyn_ros.learn.support import SUPPORT_DIRECTIONS, tilt_barriers

    a = 0.05
    cube = trimesh.creation.box(extents=(2 * a,) * 3)
    exact = GRAVITY * a * (math.sqrt(2) - 1)
    faces = [k * SUPPORT_DIRECTIONS // 4 for k in range(4)]
    out: dict = {"corner_gap_cm": {}, "barrier_ratio": {}}
    for n in (128, 1024):
        gaps, errs = [], []
        for seed in range(samplings):
            pts = np.asarray(trimesh.sample.sample_surface(cube, n, seed=seed)[0])
            gaps.append(np.median(np.linalg.norm(pts[:, None] - cube.vertices[None], axis=2).min(axis=0)))
            errs.append(np.median(np.abs(tilt_barriers(pts, np.zeros(3))[faces] / exact - 1.0)))
        out["corner_gap_cm"][n] = round(100 * float(np.median(gaps)), 2)
        out["barrier_ratio"][n] = {"median": round(float(np.median(errs)), 4),
                                   "p90": round(float(np.percentile(errs, 90)), 4)}
        print(f"{n:5d} points: corners {out['corner_gap_cm'][n]:.2f} cm from the nearest point (median), tilt "
              f"barriers off by {100 * out['barrier_ratio'][n]['median']:.1f} % (median; p90 "
              f"{100 * out['barrier_ratio'][n]['p90']:.1f} %) over {samplings} samplings")
    return out


def rotation(checkpoint: str, data: str, worst: int = 5) -> dict:
    import torch
    from scipy.spatial.transform import Rotation

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import model_rollouts
    from physdyn_ros.learn.windows import load_sims

    torch.set_num_threads(1)
    model, _ = load_model(checkpoint)
    sims = load_sims(data, ["test"])
    index = np.arange(len(sims))
    traj = model_rollouts(model, sims, index, 60)
    keep = sims.topple_index[index] < 0
    pred, true = Rotation.from_quat(traj.quat[keep, 60]), Rotation.from_quat(sims.quat[index[keep], 60])
    err = (true * pred.inv()).as_rotvec()
    total = np.degrees(np.linalg.norm(err, axis=1))
    shapes = np.asarray(sims.shape_id[index[keep]]).astype(str)
    per_shape = {s: float(np.median(total[shapes == s])) for s in sorted(set(shapes.tolist()))}
    top = dict(sorted(per_shape.items(), key=lambda kv: -kv[1])[:worst])
    start = Rotation.from_quat(sims.quat[index[keep], 0])
    turned = true * start.inv()
    turn = turned.magnitude()
    # by the initial spin about the vertical: how far the model turns the object against how far it turns
    true_yaw = np.abs(turned.as_rotvec()[:, 2])
    pred_yaw = np.abs((pred * start.inv()).as_rotvec()[:, 2])
    spin0 = np.abs(sims.ang_vel[index[keep], 0, 2])
    by_spin = {}
    for lo, hi in SPIN_BINS:
        m = (spin0 >= lo) & (spin0 < hi)
        if m.any():
            by_spin[f"{lo:g}-{hi:g}"] = {
                "n": int(m.sum()), "error_median_deg": round(float(np.median(total[m])), 2),
                "turn_ratio_median": round(float(np.median(pred_yaw[m] / np.maximum(true_yaw[m], 1e-4))), 2)}
    out = {"n": int(keep.sum()), "error_median_deg": round(float(np.median(total)), 2),
           "yaw_median_deg": round(float(np.degrees(np.median(np.abs(err[:, 2])))), 2),
           "tilt_median_deg": round(float(np.degrees(np.median(np.linalg.norm(err[:, :2], axis=1)))), 2),
           "true_turn_median_deg": round(float(np.degrees(np.median(turn))), 2),
           "worst": {k: round(v, 1) for k, v in top.items()}, "by_spin": by_spin}
    print(f"{data}: {out['n']} pushes that do not topple; final rotation error median {out['error_median_deg']}°, "
          f"yaw part {out['yaw_median_deg']}°, tilt part {out['tilt_median_deg']}°; the objects turn "
          f"{out['true_turn_median_deg']}° (median); largest per-shape medians: "
          + ", ".join(f"{k} {v:.1f}°" for k, v in out["worst"].items()))
    for name, b in by_spin.items():
        print(f"  initial spin {name} rad/s: {b['n']} pushes, error median {b['error_median_deg']}°, predicted / true "
              f"turn about z median {b['turn_ratio_median']}")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default=str(ROOT / "physdyn_ros" / "models" / "default.pt"))
    ap.add_argument("--data", default=None, help="dataset for the rotation split (its test split)")
    ap.add_argument("--samplings", type=int, default=50)
    args = ap.parse_args()
    if args.samplings < 1:
        ap.error("--samplings must be >= 1")
    result = density(args.samplings)
    if args.data:
        result["rotation"] = rotation(args.checkpoint, args.data)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
