#!/usr/bin/env python3
# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The accuracy cost of bf16 roll-outs: the same held-out pushes rolled out in float32 and in bf16, side by side.

    .venv/bin/python bench/precision.py --data data/pybullet_test [--data DIR ...] [--max-pushes N]

Both runs follow `physdyn evaluate`'s protocol (learn/evaluate.model_rollouts: 60-step closed-loop roll-outs from
the true state right after the push, the whole-push topple head, the rules, batches of --batch-size), once with
the float32 kernel and once with the bf16 one (precision forced, so it runs on any CPU: without bf16 arithmetic
torch emulates it, slower but the same numbers up to the products' rounding). Per dataset and over all:
* the change of the final position per push, |bf16 - fp32| at frame H (cm): median, p90, max;
* the final position error against the simulation (cm) over the pushes that do not topple (the model card's
  figure), median and p90 for each precision, and their changes;
* whole-push topple decisions (any frame with p > 0.5, as evaluate's F1) identical between the two, in % of all
  pushes, and F1 for each.
The bounds (the model card's): final position median changed by at most 0.1 cm and p90 by at most 0.3 cm, topple
decisions identical on at least 99.5 % of the pushes. The last line is one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, cast

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The model card's bounds on bf16's accuracy cost.
MAX_MEDIAN_CHANGE_CM, MAX_P90_CHANGE_CM, MIN_TOPPLE_AGREEMENT = 0.1, 0.3, 0.995


class FixedPrecision:
    """A DynamicsModel whose roll-outs run in one precision (what evaluate.model_rollouts calls is unchanged)."""

    def __init__(self, model: Any, precision: str) -> None:
        self._model = model
        self._precision = precision

    def rollout(self, *args: Any, **kwargs: Any) -> Any:
        return self._model.rollout(*args, precision=self._precision, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._model, name)


def compare(model: Any, data: str, split: str, max_pushes: int | None, horizon: int, batch_size: int) -> dict:
    """fp32 and bf16 roll-outs of one dataset's split: per-push arrays for summarize()."""
    import torch

    from physdyn_ros.learn.evaluate import ground_truth, model_rollouts, pose_errors
    from physdyn_ros.learn.windows import load_sims

    sims = load_sims(data, [split])
    index = np.arange(len(sims))
    if max_pushes is not None and max_pushes < len(index):
        index = np.linspace(0, len(sims) - 1, max_pushes).astype(np.int64)
    gt = ground_truth(sims, index, horizon)
    out: dict[str, Any] = {"toppled": sims.topple_index[index] >= 0, "seconds": {}}
    for precision in ("fp32", "bf16"):
        t0 = time.thread_time()
        with torch.inference_mode():
            traj = model_rollouts(cast(Any, FixedPrecision(model, precision)), sims, index, horizon,
                                  batch_size=batch_size)
        out["seconds"][precision] = time.thread_time() - t0
        errors = pose_errors(traj, gt)
        assert traj.topple_prob is not None  # the model's roll-outs always carry them
        out[precision] = {"pos": traj.pos[:, -1], "err": errors["pos"][:, -1], "rot_err": errors["rot"][:, -1],
                          "topple": np.any(traj.topple_prob[:, 1:] > 0.5, axis=1)}
    return out


def summarize(runs: list[dict]) -> dict[str, Any]:
    """The figures of the module docstring over the pushes of `runs`."""
    from physdyn_ros.learn.evaluate import topple_scores

    cat = lambda p, k: np.concatenate([r[p][k] for r in runs])  # noqa: E731
    toppled = np.concatenate([r["toppled"] for r in runs])
    calm = ~toppled
    moved = np.linalg.norm(cat("bf16", "pos") - cat("fp32", "pos"), axis=-1) * 100.0
    res: dict[str, Any] = {"pushes": int(len(toppled)), "pushes_not_toppling": int(calm.sum()),
                           "final_pos_change_cm": {"median": float(np.median(moved)),
                                                   "p90": float(np.percentile(moved, 90)), "max": float(moved.max())}}
    for p in ("fp32", "bf16"):
        err, rot = cat(p, "err")[calm], cat(p, "rot_err")[calm]
        res[p] = {"final_pos_cm_median": float(np.median(err)), "final_pos_cm_p90": float(np.percentile(err, 90)),
                  "final_rot_deg_median": float(np.median(rot)), "final_rot_deg_p90": float(np.percentile(rot, 90)),
                  "topple_f1": topple_scores(cat(p, "topple"), toppled)["f1"]}
    res["median_change_cm"] = abs(res["bf16"]["final_pos_cm_median"] - res["fp32"]["final_pos_cm_median"])
    res["p90_change_cm"] = abs(res["bf16"]["final_pos_cm_p90"] - res["fp32"]["final_pos_cm_p90"])
    res["topple_agreement"] = float(np.mean(cat("bf16", "topple") == cat("fp32", "topple")))
    res["topple_disagreements"] = int(np.sum(cat("bf16", "topple") != cat("fp32", "topple")))
    res["within_bounds"] = bool(res["median_change_cm"] <= MAX_MEDIAN_CHANGE_CM
                                and res["p90_change_cm"] <= MAX_P90_CHANGE_CM
                                and res["topple_agreement"] >= MIN_TOPPLE_AGREEMENT)
    return res


def report(name: str, res: dict[str, Any]) -> None:
    a, b = res["fp32"], res["bf16"]
    ch = res["final_pos_change_cm"]
    print(f"{name}: {res['pushes']} pushes ({res['pushes_not_toppling']} without topple)")
    print(f"  final position moved by bf16: median {ch['median']:.4f} cm, p90 {ch['p90']:.4f} cm, "
          f"max {ch['max']:.3f} cm")
    print(f"  final position error median / p90: fp32 {a['final_pos_cm_median']:.3f} / {a['final_pos_cm_p90']:.3f} cm, "
          f"bf16 {b['final_pos_cm_median']:.3f} / {b['final_pos_cm_p90']:.3f} cm (changes {res['median_change_cm']:.4f}"
          f" / {res['p90_change_cm']:.4f} cm; bounds {MAX_MEDIAN_CHANGE_CM} / {MAX_P90_CHANGE_CM})")
    print(f"  final rotation error median / p90: fp32 {a['final_rot_deg_median']:.2f} / "
          f"{a['final_rot_deg_p90']:.1f} deg, bf16 {b['final_rot_deg_median']:.2f} / {b['final_rot_deg_p90']:.1f} deg")
    f1 = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731
    print(f"  whole-push topple decisions identical on {100 * res['topple_agreement']:.2f} % "
          f"({res['topple_disagreements']} differ; bound >= {100 * MIN_TOPPLE_AGREEMENT:.1f} %); F1 fp32 "
          f"{f1(a['topple_f1'])}, bf16 {f1(b['topple_f1'])}; within bounds: {res['within_bounds']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", required=True, help="dataset directory (repeat for several)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--checkpoint", default=None, help="default: the shipped model")
    ap.add_argument("--max-pushes", type=int, default=None, help="per dataset, evenly spaced (default: all)")
    ap.add_argument("--horizon", type=int, default=60)
    ap.add_argument("--batch-size", type=int, default=256, help="roll-outs per kernel call (as physdyn evaluate)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.precision import REPORTED_FLAGS, cpu_flags, cpu_has_bf16
    from physdyn_ros.resources import DEFAULT_MODEL

    torch.set_num_threads(args.threads)
    path = args.checkpoint or DEFAULT_MODEL
    model, ckpt = load_model(path, "cpu")
    model.eval()
    flags = [f for f in REPORTED_FLAGS if f in cpu_flags()]
    print(f"model {ckpt['model_id']}; torch {torch.__version__}; CPU flags {' '.join(flags) or '(none reported)'}; "
          f"bf16 arithmetic: {'yes' if cpu_has_bf16() else 'no (bf16 emulated: slower)'}")
    runs, per_data = [], {}
    for data in args.data:
        run = compare(model, data, args.split, args.max_pushes, args.horizon, args.batch_size)
        runs.append(run)
        per_data[data] = summarize([run])
        per_data[data]["cpu_seconds"] = {k: round(v, 2) for k, v in run["seconds"].items()}
        report(f"{data} ({args.split})", per_data[data])
    overall = summarize(runs)
    if len(runs) > 1:
        report("all", overall)
    print(json.dumps({"model_id": ckpt["model_id"], "cpu_flags": flags, "bf16_arithmetic": cpu_has_bf16(),
                      "split": args.split, "horizon": args.horizon, "batch_size": args.batch_size,
                      "bounds": {"median_change_cm": MAX_MEDIAN_CHANGE_CM, "p90_change_cm": MAX_P90_CHANGE_CM,
                                 "topple_agreement": MIN_TOPPLE_AGREEMENT},
                      "overall": overall, "per_dataset": per_data}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
