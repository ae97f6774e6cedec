#!/usr/bin/env python3
"""How much of the final rotation error could a correction of the predicted spin remove? (issue 11's rotation goal)

    .venv/bin/python bench/spin_budget.py [--data data/pybullet_test] [--categories C ...] [--max-sequences 0]
        [--checkpoint CKPT] [--threads 1]

The model's roll-outs are re-run on the test pushes that do not topple with each step's predicted change of spin
about z (network and prior together) multiplied by a factor k (DynamicsModel.rollout_raw's spin_scale) on a grid of
13 values from 0.25 to 2 (log-spaced, 1 among them; learn/spin_fit.py's grid). From the final rotation error (4 s)
of every push at every k:
  * k = 1: the dynamics network without a spin head (physdyn evaluate's roll-outs);
  * the best single k for all pushes (a global recalibration of the spin friction, chosen on the test answers);
  * the best k per shape (one spin friction per object, chosen on the test answers: the most any correction that
    reads only the shape can do), and per shape and initial-spin bin (0-2, 2-6, over 6 rad/s);
  * the best k per push (the ceiling of any per-push spin correction);
  * the share of pushes whose rest face changes by more than 3 degrees (the up axis in the body frame between
    frame 0 and the end): no spin correction touches that part of the error.
A checkpoint with a spin head (model.spin_head, `physdyn fit-spin`) is also rolled out with its own factors: what
the learned per-push correction recovers (the grid's explicit factors replace the head's).
Prints a table; the last line is one JSON object {n, k1: {median_deg, p90_deg, below_3deg}, global: {k, median_deg,
...}, per_shape: {...}, per_shape_spin: {...}, per_push: {...}, face_change_share, head: {...} or null}.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SPIN_BINS = ((0.0, 2.0), (2.0, 6.0), (6.0, np.inf))


def stats(err: np.ndarray) -> dict:
    return {"median_deg": round(float(np.median(err)), 2), "p90_deg": round(float(np.percentile(err, 90)), 1),
            "below_3deg": round(float(np.mean(err < 3.0)), 3)}


def best_per_group(grid: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each push's error at the factor that is best for its group (least mean log(1 + error) over the group)."""
    out = np.empty(grid.shape[1])
    for g in np.unique(groups):
        m = groups == g
        out[m] = grid[np.argmin(np.log1p(grid[:, m]).mean(1)), m]
    return out


def face_changes(sims, index: np.ndarray) -> np.ndarray:
    """Angle (deg) between the body's up axis at frame 0 and at the end: a new rest face when over a few degrees."""
    from scipy.spatial.transform import Rotation

    from physdyn_ros.learn.spin_fit import HORIZON

    a = Rotation.from_quat(sims.quat[index, 0]).inv().apply([0.0, 0.0, 1.0])
    b = Rotation.from_quat(sims.quat[index, HORIZON]).inv().apply([0.0, 0.0, 1.0])
    return np.degrees(np.arccos(np.clip((a * b).sum(1), -1.0, 1.0)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="data/pybullet_test")
    ap.add_argument("--categories", nargs="+", default=None, help="only these shape categories of the test split")
    ap.add_argument("--max-sequences", type=int, default=0, help="a fixed random subset of the test pushes (0: all)")
    ap.add_argument("--checkpoint", default=str(ROOT / "physdyn_ros" / "models" / "default.pt"))
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    if args.max_sequences < 0 or args.threads < 1:
        raise SystemExit("--max-sequences must be >= 0, --threads >= 1")
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.spin_fit import GRID, HORIZON, error_curves, head_inputs, rotation_errors
    from physdyn_ros.learn.windows import load_sims

    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    model, _ = load_model(args.checkpoint)
    if model.cfg.prior == "none":
        raise SystemExit(f"{args.checkpoint}: the model has no prior; spin_scale needs one")

    def pushes(data: str, split: str, n: int, categories=None):
        sims = load_sims(data, [split], categories=categories)
        index = np.flatnonzero(sims.topple_index < 0)
        if 0 < n < len(index):
            index = np.sort(np.random.default_rng(0).choice(index, n, replace=False))
        return sims, index

    sims, index = pushes(args.data, "test", args.max_sequences, args.categories)
    grid = error_curves(model, sims, index, noise=0.0)[0].T  # rotation errors (len(GRID), n)
    one = int(np.argmin(np.abs(GRID - 1.0)))
    spin0 = np.abs(sims.ang_vel[index, 0, 2])
    shapes = np.asarray(sims.shape_id[index]).astype(str)
    spin_bin = np.digitize(spin0, [b[1] for b in SPIN_BINS[:-1]])
    g = int(np.argmin(np.median(grid, 1)))
    out: dict = {"n": int(len(index)), "data": args.data, "k1": stats(grid[one]),
                 "global": {"k": round(float(GRID[g]), 3), **stats(grid[g])},
                 "per_shape": stats(best_per_group(grid, shapes)),
                 "per_shape_spin": stats(best_per_group(grid, np.char.add(shapes, spin_bin.astype(str)))),
                 "per_push": stats(grid.min(0)),
                 "face_change_share": round(float(np.mean(face_changes(sims, index) > 3.0)), 3),
                 "k1_by_spin": {}, "per_push_by_spin": {}, "head": None}
    for b, (lo, hi) in enumerate(SPIN_BINS):
        m = spin_bin == b
        name = f"{lo:g}-{hi:g}"
        out["k1_by_spin"][name] = stats(grid[one, m])
        out["per_push_by_spin"][name] = stats(grid.min(0)[m])
    if model.spin is not None:
        with torch.no_grad():  # the head's factors on the clouds its roll-outs see
            k = np.exp(model.spin.log_factor(torch.from_numpy(head_inputs(model, model.spin, sims, index, 0.0,
                                                                          0.0))).numpy())
        out["head"] = {"k_median": round(float(np.median(k)), 3), **stats(rotation_errors(model, sims, index, None,
                                                                                            noise=0.0))}
    elapsed = time.perf_counter() - t0
    print(f"{args.data}: {out['n']} test pushes that do not topple; final rotation error after {HORIZON} steps with "
          f"each step's predicted change of spin about z scaled by k ({elapsed:.0f} s)")
    print("| spin correction | median deg | p90 deg | share under 3 deg |\n|---|---|---|---|")
    rows = [("none (k = 1, the model)", out["k1"]), (f"one k for all pushes (best: {out['global']['k']})",
                                                     out["global"]),
            ("best k per shape", out["per_shape"]), ("best k per shape and spin bin", out["per_shape_spin"]),
            ("best k per push", out["per_push"])]
    if out["head"]:
        rows.append((f"the checkpoint's spin head (k median {out['head']['k_median']})", out["head"]))
    for label, s in rows:
        print(f"| {label} | {s['median_deg']} | {s['p90_deg']} | {s['below_3deg']} |")
    for name in out["k1_by_spin"]:
        a, b = out["k1_by_spin"][name], out["per_push_by_spin"][name]
        print(f"  initial spin {name} rad/s: k = 1 median {a['median_deg']}° ({a['below_3deg']:.0%} under 3°), "
              f"best k per push {b['median_deg']}° ({b['below_3deg']:.0%})")
    print(f"  rest face changed by more than 3°: {out['face_change_share']:.1%} of the pushes")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
