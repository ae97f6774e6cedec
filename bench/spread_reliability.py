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
"""Reliability of the predicted spread (physdyn_ros.spread) on pushes the calibration never saw.

    .venv/bin/python bench/spread_reliability.py --data data/heldout_families [--checkpoint CKPT]
        [--splits train val test] [--max-sequences 1500] [--steps-in K]

Each push (physdyn_ros.spread_fit.measure: whole cloud, true start state, 60 steps) is predicted with its
spread. For each calibrated level: the share of upright pushes whose true rest position (yaw) lies within the
predicted radius, and the median radius; at the default level also by third of the push's sensitivity (a spread
that only covers on average would miss the sensitive third); `--steps-in K` feeds the K true states after the push
first, as the predictor node's refinements do. For the topple probability: its reliability bins,
and the decisions' error rate and Brier score by topple spread. The last line is one JSON object
{pushes, upright, levels: {level: {position_coverage, yaw_coverage, position_radius_median_cm,
yaw_radius_median_deg}}, position_coverage_by_third, topple_spread_bins: [{spread, n, error_rate, brier}],
topple_reliability: [...], brier}.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SPREAD_BINS = (0.0, 0.01, 0.05, 1.0)


def main() -> int:
    from physdyn_ros.learn.evaluate import calibration
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.spread import DEFAULT_LEVEL
    from physdyn_ros.spread_fit import measure

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--checkpoint", default=None, help="default: the shipped model")
    ap.add_argument("--splits", nargs="+", default=["train", "val", "test"])
    ap.add_argument("--max-sequences", type=int, default=1500)
    ap.add_argument("--steps-in", type=int, default=0, help="true states after the push fed first (refinements)")
    args = ap.parse_args()

    pred = Predictor.load(args.checkpoint, threads=1)
    cal = pred.spread_calibration
    if cal is None:
        raise SystemExit(f"spread_reliability: {pred.spread_problem}")
    sims = load_sims(args.data, list(args.splits))
    index = np.linspace(0, len(sims) - 1, min(args.max_sequences, len(sims))).astype(np.int64)
    m = measure(pred, sims, index, observed=args.steps_in)
    up = ~m["toppled"]
    sens, err = m["sensitivity"][up], m["error"][up]
    print(f"{len(index)} pushes of {args.data} ({int(up.sum())} upright), {args.steps_in} states in; calibration "
          f"fitted on {cal.fitted_on}")
    print(f"{'level':>6} {'position covered':>17} {'median radius':>14} {'yaw covered':>12} {'median radius':>14}")
    levels = {}
    for level in cal.levels:
        radii = np.array([cal.radii(tuple(s), level) for s in sens])
        row = {"position_coverage": float(np.mean(err[:, 0] <= radii[:, 0])),
               "yaw_coverage": float(np.mean(err[:, 1] <= radii[:, 1])),
               "position_radius_median_cm": float(100 * np.median(radii[:, 0])),
               "yaw_radius_median_deg": float(np.degrees(np.median(radii[:, 1])))}
        levels[str(level)] = row
        print(f"{level:>6.2f} {row['position_coverage']:>17.3f} {row['position_radius_median_cm']:>11.2f} cm "
              f"{row['yaw_coverage']:>12.3f} {row['yaw_radius_median_deg']:>10.1f} deg")
    radii = np.array([cal.radii(tuple(s), DEFAULT_LEVEL) for s in sens])
    thirds = np.array_split(np.argsort(sens[:, 0], kind="stable"), 3)
    by_third = [float(np.mean(err[t, 0] <= radii[t, 0])) for t in thirds]
    print(f"position coverage at {DEFAULT_LEVEL} by third of sensitivity (low, middle, high): "
          + ", ".join(f"{c:.3f}" for c in by_third))
    prob, spread, toppled = m["topple_probability"], m["topple_spread"], m["toppled"]
    bins = []
    print(f"{'topple spread':>14} {'pushes':>7} {'wrong decisions':>16} {'Brier':>7}")
    for lo, hi in zip(SPREAD_BINS[:-1], SPREAD_BINS[1:]):
        sel = (spread >= lo) & (spread < hi)
        row = {"spread": f"{lo}-{hi}", "n": int(sel.sum()),
               "error_rate": float(np.mean((prob[sel] >= 0.5) != toppled[sel])) if sel.any() else None,
               "brier": float(np.mean((prob[sel] - toppled[sel]) ** 2)) if sel.any() else None}
        bins.append(row)
        if sel.any():
            print(f"{row['spread']:>14} {row['n']:>7} {row['error_rate']:>16.3f} {row['brier']:>7.4f}")
    rel = calibration(prob, toppled, bins=5)
    print("topple probability reliability: " + ", ".join(
        f"{r['bin']}: n {r['n']}, observed {r['observed']:.2f}" for r in rel["reliability"] if r["n"]))
    print(json.dumps({"pushes": len(index), "upright": int(up.sum()), "levels": levels,
                      "position_coverage_by_third": by_third, "topple_spread_bins": bins,
                      "topple_reliability": rel["reliability"], "brier": rel["brier"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
