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
"""The shipped ensemble (the default model and models/ensemble-*.pt) on pushes none of them trained on.

    .venv/bin/python bench/ensemble.py --data data/heldout_families [--splits train val test]
        [--max-sequences 1500] [--members 5]

Each push: the whole cloud at the true start pose, the true velocities after the push, 60 steps (4 s), every
member. Printed: each member's rest-position error (median / p90 over upright pushes) and topple F1 / Brier of
its whole-push probability; the same for the members' mean position and mean probability, and the F1 of the
highest member's probability (what the planner holds to its limit). Whether the members' disagreement (RMS
distance of their rest positions from their mean) says where the model errs: the share of upright pushes whose
true rest lies within k disagreements of the mean, the error by third of disagreement, and the rank correlation
of disagreement and error, beside the same for the default model's own sensitivity (physdyn_ros.spread). The
last line is one JSON object {pushes, upright, members: [{model_id, position_median_cm, position_p90_cm,
topple_f1, brier}], mean: {...}, max_topple_f1, coverage: {k: share}, error_by_third_cm, spearman_disagreement,
spearman_sensitivity}.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

HORIZON = 60


def rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(a, b).statistic)


def motion(err: np.ndarray) -> dict:
    return {"position_median_cm": round(float(100 * np.median(err)), 3),
            "position_p90_cm": round(float(100 * np.percentile(err, 90)), 3)}


def main() -> int:
    from physdyn_ros.geometry import quat_rotate
    from physdyn_ros.learn.evaluate import topple_scores
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import ensemble_models

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--splits", nargs="+", default=["train", "val", "test"])
    ap.add_argument("--max-sequences", type=int, default=1500)
    ap.add_argument("--members", type=int, default=5, help="the default model and this many minus one shipped ones")
    args = ap.parse_args()

    paths = [None] + ensemble_models()[:args.members - 1]
    if len(paths) < 2 or len(paths) != args.members:
        raise SystemExit(f"ensemble: {args.members} members asked, {len(paths)} shipped (models/ensemble-*.pt)")
    models = [Predictor.load(p, threads=1) for p in paths]
    sims = load_sims(args.data, list(args.splits))
    if sims.num_frames <= HORIZON:
        raise SystemExit(f"ensemble: the dataset's {sims.num_frames} frames do not reach the {HORIZON}-step rest")
    index = np.linspace(0, len(sims) - 1, min(args.max_sequences, len(sims))).astype(np.int64)
    rest = np.zeros((len(models), len(index), 2))
    prob = np.zeros((len(models), len(index)))
    sens = np.zeros(len(index))
    for j, i in enumerate(index):
        pts = sims.points[sims.shape_index[i]].astype(np.float64) * sims.scale[i].astype(np.float64)
        q0, p0 = sims.quat[i, 0].astype(np.float64), sims.pos[i, 0].astype(np.float64)
        cloud = quat_rotate(np.broadcast_to(q0, pts.shape[:1] + (4,)), pts) + p0
        for m, model in enumerate(models):
            traj = model.rollout(model.encode(cloud), sims.lin_vel[i, 0], sims.ang_vel[i, 0], HORIZON, position=p0,
                                 spread=m == 0)
            rest[m, j], prob[m, j] = traj.positions[-1, :2], traj.topple_probability
            if m == 0:
                sens[j] = traj.spread.sensitivity[0]
    truth = sims.pos[index, HORIZON, :2]
    toppled = sims.toppled[index, :HORIZON + 1].any(axis=1)
    up = ~toppled
    print(f"{len(index)} pushes of {args.data} ({int(up.sum())} upright), {len(models)} members, {HORIZON} steps")
    print(f"{'model':<28} {'position median / p90 cm':>25} {'topple F1 (P / R)':>20} {'Brier':>7}")

    def row(name: str, xy: np.ndarray, p: np.ndarray) -> dict:
        err = np.linalg.norm(xy - truth, axis=1)[up]
        s = topple_scores(p >= 0.5, toppled)
        out = {"model_id": name, **motion(err), "topple_f1": round(s["f1"] or 0.0, 3),
               "brier": round(float(np.mean((p - toppled) ** 2)), 4)}
        print(f"{name:<28} {out['position_median_cm']:>12.2f} / {out['position_p90_cm']:<10.2f} "
              f"{s['f1'] or 0:>8.3f} ({s['precision'] or 0:.2f} / {s['recall'] or 0:.2f}) {out['brier']:>7.4f}")
        return out

    members = [row(mdl.model_id, rest[m], prob[m]) for m, mdl in enumerate(models)]
    centre = rest.mean(axis=0)
    mean = row("members' mean", centre, prob.mean(axis=0))
    high = topple_scores(prob.max(axis=0) >= 0.5, toppled)
    print(f"highest member's topple probability: F1 {high['f1']:.3f} (P {high['precision']:.2f} / "
          f"R {high['recall']:.2f})")
    err = np.linalg.norm(centre - truth, axis=1)[up]
    spread = np.sqrt(np.mean(np.sum((rest - centre) ** 2, axis=-1), axis=0))[up]
    coverage = {str(k): round(float(np.mean(err <= k * spread)), 3) for k in (1, 2, 3, 5)}
    print("true rest within k disagreements of the mean: " + ", ".join(f"k={k}: {v:.3f}" for k, v in coverage.items()))
    thirds = np.array_split(np.argsort(spread, kind="stable"), 3)
    by_third = [round(float(100 * np.median(err[t])), 3) for t in thirds]
    print(f"median error by third of disagreement (low, middle, high): {by_third} cm; disagreement medians "
          f"{[round(float(100 * np.median(spread[t])), 3) for t in thirds]} cm")
    rho_d = rank_correlation(spread, err)
    own = np.linalg.norm(rest[0] - truth, axis=1)[up]
    rho_s = rank_correlation(sens[up], own)
    print(f"rank correlation with the error: disagreement {rho_d:.3f}; the default model's sensitivity {rho_s:.3f}")
    print(json.dumps({"pushes": len(index), "upright": int(up.sum()), "members": members, "mean": mean,
                      "max_topple_f1": round(high["f1"], 3), "coverage": coverage, "error_by_third_cm": by_third,
                      "spearman_disagreement": round(rho_d, 3), "spearman_sensitivity": round(rho_s, 3)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
