#!/usr/bin/env python3
"""Four measurements behind the topple head's inputs and the rotation goal (issue 11).

    .venv/bin/python bench/topple_inputs.py [--checkpoint CKPT] [--data data/pybullet_test] [--split test]
        [--max-sequences 0] [--samplings 50] [--loss-sensitivity]

1. Descriptor density: a 10 cm cube sampled `--samplings` times with 128 and with 1024 random surface points
   (trimesh, seeds 0..): the distance from its corners to the nearest sampled point, and its tilt barriers toward
   its four faces (support.tilt_barriers) against the exact g a (sqrt(2) - 1). Why inputs version 6 reads 1024.
2. Rotation error split (with --data): the checkpoint's 60-step roll-outs (physdyn evaluate's, learn/evaluate.py
   model_rollouts) on the dataset's --split (test; --max-sequences: a fixed random subset); over the pushes
   that do not topple, the final rotation error and its yaw (z) and tilt (x, y) parts as a rotation vector in
   world axes, the true turn, the shapes with the largest median error, and by initial spin about z (bins in
   rad/s) the error and how far the model turns the object about z against how far it turns (median of the
   ratio, over the pushes that turn more than 2°; the turns are the sums of the steps' yaw increments, so
   several revolutions count as such).
3. Spin deceleration (with --data, the same pushes): the checkpoint fed the true velocities at every step
   (teacher-forced, model_single_step's setting) against the data, per step by the spin |w_z| before it (the
   same bins, the first 800 pushes): the mean deceleration of |w_z| predicted and true and their ratio; and per
   category (its first 150 pushes, steps spinning over 2 rad/s) the predicted and the model's prior's (mu g / r,
   times the learned lever where the model has one) against the true. Over 1 the network stops the spin too
   soon, whatever the roll-out does with it.
4. Loss sensitivity (with --data and --loss-sensitivity, on --split; train: the loss the model was trained on):
   the network's residual on the spin's change (its d_angvel_z output over the prior) scaled 0.8x / 1x / 1.2x,
   on 2048 fixed random training windows of the checkpoint's window length: every weighted term of the
   checkpoint's own loss, teacher-forced and closed-loop, and the teacher-forced deceleration (spin over 2 rad/s)
   against the data's. How much the training loss sees the spin's deceleration at all.
Prints all; the last line is one JSON object: corner_gap_cm {128, 1024}, barrier_ratio {128, 1024} (median and
p90 of |barrier / exact - 1|), and with --data rotation {n, error_median_deg, yaw_median_deg, tilt_median_deg,
true_turn_median_deg, worst: {shape: median deg}, by_spin: {bin: {n, error_median_deg, turn_ratio_median}},
spin_decel: {by_spin: {bin: {steps, true_mean, pred_mean, ratio}}, by_category: {category: {steps, true_mean,
pred_ratio, prior_ratio}}} (rad/s per step)}, and with --loss-sensitivity loss_sensitivity {scale: {teacher_forced:
{term: weighted loss}, closed_loop: {...}, decel_ratio}}.
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


def turned_about_z(quat: np.ndarray) -> np.ndarray:
    """Total turn about the world z (rad) of orientations (B, T, 4): the sum of the steps' yaw increments."""
    from scipy.spatial.transform import Rotation

    total = np.zeros(quat.shape[0])
    for t in range(quat.shape[1] - 1):
        total += (Rotation.from_quat(quat[:, t + 1]) * Rotation.from_quat(quat[:, t]).inv()).as_rotvec()[:, 2]
    return total


def spin_deceleration(model, sims, index: np.ndarray, horizon: int = 60, per_bin: int = 800,
                      per_category: int = 150) -> dict:
    """Teacher-forced deceleration of |w_z| per step, predicted, true and the model's prior's (mu g / r, or the
    learned lever's), by the spin before the step (the first `per_bin` pushes of `index`) and per category (spin
    over 2 rad/s, the first `per_category` pushes of each category among `index`)."""
    import torch

    from physdyn_ros.learn.prior import sliding_step
    from physdyn_ros.learn.windows import sequences

    def decelerations(rows: np.ndarray) -> tuple[np.ndarray, ...]:
        pred, true, prior, spin = [], [], [], []
        with torch.inference_mode():
            for start in range(0, len(rows), 200):
                seq = sequences(sims, horizon, model.cfg.num_points, rows[start:start + 200])
                feature = model.encode(seq["cloud"])
                vel, angvel = seq["vel"][:, :-1], seq["angvel"][:, :-1]
                raw = model.teacher_forced(feature, vel, angvel)
                pred.append(model.denormalize(raw)["d_angvel"][..., 2].numpy())
                true.append(seq["d_angvel"][..., 2].numpy())
                spin.append(angvel[..., 2].numpy())
                if model.cfg.prior != "none":
                    steps = [c[:, None].expand(-1, vel.shape[1]) for c in model._prior_decel(feature)]
                    prior.append(sliding_step(vel, angvel, *steps)[1][..., 2].numpy())
                else:
                    prior.append(np.zeros_like(spin[-1]))
        return tuple(np.concatenate(a).ravel() for a in (pred, true, prior, spin))

    def mean_decel(values: np.ndarray, spin: np.ndarray) -> float:  # along the spin: positive slows it down
        return float(np.mean(-values * np.sign(spin)))

    p, t, pr, w = decelerations(index[:per_bin])
    by_spin = {}
    for lo, hi in SPIN_BINS[1:]:  # below 0.5 rad/s the sign of the spin is noise
        m = (np.abs(w) >= lo) & (np.abs(w) < hi)
        if m.any():
            pd, td = mean_decel(p[m], w[m]), mean_decel(t[m], w[m])
            by_spin[f"{lo:g}-{hi:g}"] = {"steps": int(m.sum()), "true_mean": round(td, 3), "pred_mean": round(pd, 3),
                                         "ratio": round(pd / td, 3) if td > 0 else None}
    categories = np.asarray(sims.category).astype(str)
    by_category = {}
    for cat in sorted(set(categories[index].tolist())):
        rows = index[categories[index] == cat][:per_category]
        p, t, pr, w = decelerations(rows)
        m = np.abs(w) > 2.0
        if m.any():
            td = mean_decel(t[m], w[m])
            by_category[cat] = {"steps": int(m.sum()), "true_mean": round(td, 3),
                                "pred_ratio": round(mean_decel(p[m], w[m]) / td, 3) if td > 0 else None,
                                "prior_ratio": round(mean_decel(pr[m], w[m]) / td, 3) if td > 0 else None}
    return {"by_spin": by_spin, "by_category": by_category}


def rotation(checkpoint: str, data: str, split: str = "test", max_sequences: int = 0, worst: int = 5) -> dict:
    import torch
    from scipy.spatial.transform import Rotation

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import model_rollouts
    from physdyn_ros.learn.windows import load_sims

    torch.set_num_threads(1)
    model, _ = load_model(checkpoint)
    sims = load_sims(data, [split])
    index = np.arange(len(sims))
    if 0 < max_sequences < len(index):  # a fixed random subset (each category keeps its share on average)
        index = np.sort(np.random.default_rng(0).choice(index, max_sequences, replace=False))
    traj = model_rollouts(model, sims, index, 60)
    keep = sims.topple_index[index] < 0
    pred, true = Rotation.from_quat(traj.quat[keep, 60]), Rotation.from_quat(sims.quat[index[keep], 60])
    err = (true * pred.inv()).as_rotvec()
    total = np.degrees(np.linalg.norm(err, axis=1))
    shapes = np.asarray(sims.shape_id[index[keep]]).astype(str)
    per_shape = {s: float(np.median(total[shapes == s])) for s in sorted(set(shapes.tolist()))}
    top = dict(sorted(per_shape.items(), key=lambda kv: -kv[1])[:worst])
    start = Rotation.from_quat(sims.quat[index[keep], 0])
    turn = (true * start.inv()).magnitude()
    # by the initial spin about the vertical: how far the model turns the object against how far it turns
    true_yaw = turned_about_z(sims.quat[index[keep], :61])
    pred_yaw = turned_about_z(traj.quat[keep, :61])
    spin0 = np.abs(sims.ang_vel[index[keep], 0, 2])
    by_spin = {}
    for lo, hi in SPIN_BINS:
        m = (spin0 >= lo) & (spin0 < hi)
        turning = m & (np.abs(true_yaw) > math.radians(2.0))
        if m.any():
            by_spin[f"{lo:g}-{hi:g}"] = {
                "n": int(m.sum()), "error_median_deg": round(float(np.median(total[m])), 2),
                "turn_ratio_median": (round(float(np.median(pred_yaw[turning] / true_yaw[turning])), 2)
                                      if turning.any() else None)}
    out = {"n": int(keep.sum()), "error_median_deg": round(float(np.median(total)), 2),
           "yaw_median_deg": round(float(np.degrees(np.median(np.abs(err[:, 2])))), 2),
           "tilt_median_deg": round(float(np.degrees(np.median(np.linalg.norm(err[:, :2], axis=1)))), 2),
           "true_turn_median_deg": round(float(np.degrees(np.median(turn))), 2),
           "worst": {k: round(v, 1) for k, v in top.items()}, "by_spin": by_spin,
           "spin_decel": spin_deceleration(model, sims, index[keep])}
    print(f"{data}: {out['n']} pushes that do not topple; final rotation error median {out['error_median_deg']}°, "
          f"yaw part {out['yaw_median_deg']}°, tilt part {out['tilt_median_deg']}°; the objects turn "
          f"{out['true_turn_median_deg']}° (median); largest per-shape medians: "
          + ", ".join(f"{k} {v:.1f}°" for k, v in out["worst"].items()))
    for name, b in by_spin.items():
        print(f"  initial spin {name} rad/s: {b['n']} pushes, error median {b['error_median_deg']}°, predicted / true "
              f"turn about z median {b['turn_ratio_median']}")
    for name, b in out["spin_decel"]["by_spin"].items():
        print(f"  spin {name} rad/s, teacher-forced: {b['steps']} steps, deceleration predicted {b['pred_mean']} "
              f"against {b['true_mean']} rad/s per step ({b['ratio']}x)")
    print("  spin deceleration over 2 rad/s by category (teacher-forced), predicted / true and the prior's / true:")
    for cat, b in sorted(out["spin_decel"]["by_category"].items(), key=lambda kv: kv[1]["pred_ratio"] or 0):
        print(f"    {cat:16s} {b['steps']:5d} steps, true {b['true_mean']:.2f} rad/s per step, predicted "
              f"{b['pred_ratio']}x, prior {b['prior_ratio']}x")
    return out


def loss_sensitivity(checkpoint: str, data: str, split: str, windows: int = 2048,
                     scales: tuple = (0.8, 1.0, 1.2)) -> dict:
    """How much the training loss (the checkpoint's own loss config) sees the spin's deceleration: the network's
    residual on the spin's change (its output d_angvel_z, over the prior) scaled by each of `scales`, on
    `windows` fixed random training windows of the split, teacher-forced and closed-loop: each weighted term, and
    the teacher-forced deceleration over 2 rad/s against the data's."""
    import copy

    import torch

    from physdyn_ros.learn.checkpoint import load_checkpoint, load_model
    from physdyn_ros.learn.losses import LossConfig
    from physdyn_ros.learn.train import batch_loss, resolve_config
    from physdyn_ros.learn.windows import load_sims, make_windows, random_starts

    torch.set_num_threads(1)
    base, _ = load_model(checkpoint)
    stored = load_checkpoint(checkpoint)["config"]  # its loss and window (a head's fit adds other sections)
    cfg = resolve_config({k: stored.get(k) for k in ("model", "loss", "train", "data")})
    loss_cfg, window = LossConfig.from_dict(cfg["loss"]), int(cfg["train"]["window"])
    sims = load_sims(data, [split])
    index = np.sort(np.random.default_rng(0).choice(len(sims), min(windows, len(sims)), replace=False))
    starts = random_starts(sims, index, window, np.random.default_rng(1))
    batches = [make_windows(sims, index[i:i + 256], starts[i:i + 256], window, base.cfg.num_points, None)
               for i in range(0, len(index), 256)]
    if base.cfg.cell != "lstm":
        raise ValueError("--loss-sensitivity scales the recurrent head's output: an LSTM model is needed")
    # every weighted term the loss config switches on (the per-step loss names are the w_<name> keys), and the total
    weights = {k[2:]: float(v) for k, v in loss_cfg.to_dict().items() if k.startswith("w_") and float(v) > 0}
    weights["total"] = 1.0
    out: dict = {}
    for scale in scales:
        model = copy.deepcopy(base).eval()
        with torch.no_grad():  # the residual's d_angvel_z: the recurrent head's row and the input skip's
            model.head.weight[5] *= scale
            model.head.bias[5] *= scale
            if model.skip is not None:
                model.skip.weight[5] *= scale
        row: dict = {}
        pred, true, spin = [], [], []
        with torch.no_grad():
            for mode, feedback in (("teacher_forced", False), ("closed_loop", True)):
                sums: dict = {}
                for batch in batches:
                    _, parts = batch_loss(model, model, batch, loss_cfg, feedback)
                    for k in weights:
                        if k in parts:  # com only with a centre-of-mass head
                            sums[k] = sums.get(k, 0.0) + weights[k] * float(parts[k]) / len(batches)
                row[mode] = {k: round(v, 5) for k, v in sums.items()}
            for batch in batches:
                raw = model.teacher_forced(model.encode(batch["cloud"]), batch["vel"][:, :-1], batch["angvel"][:, :-1])
                pred.append(model.denormalize(raw)["d_angvel"][..., 2])
                true.append(batch["d_angvel"][..., 2])
                spin.append(batch["angvel"][:, :-1, 2])
        p, t, w = (torch.cat(a).numpy().ravel() for a in (pred, true, spin))
        m = np.abs(w) > 2.0
        td = float(np.mean(-t[m] * np.sign(w[m]))) if m.any() else 0.0
        row["decel_ratio"] = round(float(np.mean(-p[m] * np.sign(w[m]))) / td, 3) if td > 0 else None
        out[f"{scale:g}"] = row
    print(f"loss sensitivity ({data} {split}, {len(index)} windows): the residual on the spin's change scaled by "
          + ", ".join(f"{k}: deceleration {v['decel_ratio']}x the data's" for k, v in out.items()))
    for mode in ("teacher_forced", "closed_loop"):
        for term in next(iter(out.values()))[mode]:
            print(f"  {mode:14s} {term:7s} " + "  ".join(f"{out[k][mode][term]:.4f}" for k in out))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default=str(ROOT / "physdyn_ros" / "models" / "default.pt"))
    ap.add_argument("--data", default=None, help="dataset for the rotation split")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"),
                    help="its split (train: how the model fits the pushes it was trained on)")
    ap.add_argument("--max-sequences", type=int, default=0, help="a fixed random subset of the split (0: all)")
    ap.add_argument("--samplings", type=int, default=50)
    ap.add_argument("--loss-sensitivity", action="store_true",
                    help="with --data: how much the training loss sees the spin's deceleration (on --split)")
    args = ap.parse_args()
    if args.samplings < 1 or args.max_sequences < 0:
        ap.error("--samplings must be >= 1 and --max-sequences >= 0")
    result = density(args.samplings)
    if args.data:
        result["rotation"] = rotation(args.checkpoint, args.data, args.split, args.max_sequences)
        if args.loss_sensitivity:
            result["loss_sensitivity"] = loss_sensitivity(args.checkpoint, args.data, args.split)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
