"""Generalization experiments of the paper (Sec. 5): leave-one-category-out and friction with "steps in".

Leave-one-category-out: for each category c, a model trained without c (data.exclude_categories=[c]) against a
model trained on all categories with the same config and budget, both on c's unseen test shapes.
Friction: a model trained with per-simulation friction ~ U(0.35, 0.65) against one trained at constant friction
0.5, on the varied-friction test split, with 1, 4 and 6 observed frames fed before the roll-out runs free.

    .venv/bin/python bench/generalization.py --loo-runs RUNS --loo-data data/combined \
        --friction-data data/speakers_varied --varied RUNS/FRIC_VAR/model_best.pt \
        --constant RUNS/FRIC_CONST/model_best.pt --out runs/generalization

RUNS holds ALL/model_best.pt and LOO_<category>/model_best.pt (see the model card for how they were trained).
Prints markdown tables; writes OUT/generalization.json and OUT/generalization.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from physdyn_ros.data.format import write_json
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
        if not (args.varied and args.constant):
            raise SystemExit("error: --friction-data needs --varied and --constant checkpoints")
        lines += ["## Friction ~ U(0.35, 0.65) on unseen speakers, by observed frames (steps in)", "",
                  COLUMNS.replace("test shapes", "steps in"), "|---|---|---|---|---|---|---|---|"]
        for k in (1, 4, 6):
            for name, ckpt in (("constant-friction model", args.constant), ("varied-friction model", args.varied)):
                m = metrics(ckpt, args.friction_data, None, k, args.max_sequences)
                report.setdefault("friction", {}).setdefault(str(k), {})[name] = m
                lines.append(row(name, str(k), m))
        lines.append("")
    text = "\n".join(lines)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / "generalization.json", report)
    (args.out / "generalization.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
