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
"""Generalization experiments of the paper (Sec. 5): leave-one-category-out and friction with "steps in".

Leave-one-category-out: for each category c, a model trained without c (data.exclude_categories=[c]) against a
model trained on all categories with the same config and budget, both on c's unseen test shapes.
Friction: a model trained with per-simulation friction ~ U(0.35, 0.65) against one trained at constant friction
0.5 (either may be left out), on the varied-friction test split, with 1, 4 and 6 observed frames fed before the
roll-out runs free. A test split with held-out families (the generator's leave_out) is reported in two groups:
the held-out families and the trained ones.

    .venv/bin/python bench/generalization.py --loo-runs RUNS --loo-data data/combined \
        --friction-data data/speakers_varied --varied RUNS/FRIC_VAR/model_best.pt \
        --constant RUNS/FRIC_CONST/model_best.pt --out runs/generalization
    # the shipped model (trained at friction 0.5) on the broad world's shapes at friction ~ U(0.35, 0.65):
    physdyn generate data/friction_varied --config generate_broad --vary-friction --num-sims 4000 --workers 2
    .venv/bin/python bench/generalization.py --friction-data data/friction_varied \
        --constant physdyn_ros/models/default.pt --out runs/friction

RUNS holds ALL/model_best.pt and LOO_<category>/model_best.pt (see the model card for how they were trained).
Prints markdown tables; writes OUT/generalization.json and OUT/generalization.md; the last line is one JSON
object: {"leave_one_out": {category: {model: figures}}, "friction": {steps_in: {"model @ group": figures}}} with
figures {pos_median, pos_p90, rot_median, rot_p90, f1, n}.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from physdyn_ros.data.format import Dataset, write_json
from physdyn_ros.learn.checkpoint import load_model
from physdyn_ros.learn.evaluate import evaluate_all, ground_truth, model_rollouts
from physdyn_ros.learn.windows import load_sims

COLUMNS = "| model | test shapes | n | roll-out P cm/step | roll-out \\|θ\\| °/step | final P cm median / p90 | " \
          "final rot ° median / p90 | topple F1 |"


def metrics(ckpt: Path, data: str, categories: list[str] | None, steps_in: int, max_sequences: int,
            horizon: int = 60) -> dict[str, Any]:
    model, _ = load_model(ckpt)
    sims = load_sims(data, ["test"], categories=categories)
    index = np.arange(len(sims))
    if len(index) > max_sequences:
        index = np.linspace(0, len(sims) - 1, max_sequences).astype(np.int64)
    traj = model_rollouts(model, sims, index, horizon, steps_in)
    gt = ground_truth(sims, index, horizon)
    return evaluate_all({"model": traj}, {}, gt, sims, index, horizon)["overall"]["model"]


def row(name: str, shapes: str, m: dict[str, Any]) -> str:
    def f(x: Any, d: int = 2) -> str:
        return "–" if x is None else f"{x:.{d}f}"

    r, p, q = m["rollout_step"], m["final_pos_cm"], m["final_rot_deg"]
    f1 = m.get("topple", {}).get("f1")
    return (f"| {name} | {shapes} | {m['sequences']} | {f(r['p'], 3)} | {f(r['angle'])} | {f(p['median'])} / "
            f"{f(p['p90'])} | {f(q['median'])} / {f(q['p90'])} | {f(f1, 3)} |")


def compact(m: dict[str, Any]) -> dict[str, Any]:
    p, q = m["final_pos_cm"], m["final_rot_deg"]
    return {"pos_median": p["median"], "pos_p90": p["p90"], "rot_median": q["median"], "rot_p90": q["p90"],
            "f1": m.get("topple", {}).get("f1"), "n": m["sequences"]}


def friction_groups(data: str) -> list[tuple[str, list[str] | None]]:
    """[(name, categories)]: the held-out families and the trained ones apart when the dataset has both."""
    groups = Dataset(data).manifest.get("test_groups") or {}
    held, trained = list(groups.get("held_out") or []), list(groups.get("in_category") or [])
    if not held:
        return [("all test shapes", None)]
    return [("held-out families", held), ("trained families", trained)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--loo-runs", type=Path, help="folder with ALL/ and LOO_<category>/ runs")
    ap.add_argument("--loo-data", default="data/combined")
    ap.add_argument("--friction-data", default=None, help="varied-friction dataset (its test split)")
    ap.add_argument("--varied", type=Path, help="checkpoint trained with varied friction")
    ap.add_argument("--constant", type=Path, help="checkpoint trained with constant friction")
    ap.add_argument("--max-sequences", type=int, default=300, help="per evaluated group")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    report: dict[str, Any] = {}
    lines: list[str] = []
    if args.loo_runs:
        cats = sorted(p.name[4:] for p in args.loo_runs.glob("LOO_*") if (p / "model_best.pt").is_file())
        if not cats or not (args.loo_runs / "ALL" / "model_best.pt").is_file():
            raise SystemExit(f"error: {args.loo_runs} needs ALL/model_best.pt and LOO_<category>/model_best.pt")
        lines += ["## Leave one category out (test shapes of the left-out category)", "", COLUMNS,
                  "|---|---|---|---|---|---|---|---|"]
        for c in cats:
            both = {"all categories": metrics(args.loo_runs / "ALL" / "model_best.pt", args.loo_data, [c], 1,
                                              args.max_sequences),
                    f"without {c}": metrics(args.loo_runs / f"LOO_{c}" / "model_best.pt", args.loo_data, [c], 1,
                                            args.max_sequences)}
            report.setdefault("leave_one_out", {})[c] = both
            lines += [row(k, c, v) for k, v in both.items()]
        lines.append("")
    if args.friction_data:
        models = [(n, c) for n, c in (("constant-friction model", args.constant), ("varied-friction model",
                                                                                  args.varied)) if c]
        if not models:
            raise SystemExit("error: --friction-data needs a --varied or a --constant checkpoint (or both)")
        lines += ["## Friction ~ U(0.35, 0.65) on unseen shapes, by observed frames (steps in)", "",
                  COLUMNS.replace("| test shapes |", "| test shapes, steps in |"), "|---|---|---|---|---|---|---|---|"]
        for k in (1, 4, 6):
            for group, cats in friction_groups(args.friction_data):
                for name, ckpt in models:
                    m = metrics(ckpt, args.friction_data, cats, k, args.max_sequences)
                    report.setdefault("friction", {}).setdefault(str(k), {})[f"{name} @ {group}"] = m
                    lines.append(row(name, f"{group}, {k}", m))
        lines.append("")
    text = "\n".join(lines)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "generalization.json", report)
    (args.out / "generalization.md").write_text(text + "\n")
    print(text)
    print(json.dumps({part: {key: {name: compact(m) for name, m in rows.items()} for key, rows in groups.items()}
                      for part, groups in report.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
