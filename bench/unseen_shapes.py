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
"""Shapes never seen in training: a checkpoint against the baselines, per group of test shapes.

    .venv/bin/python bench/unseen_shapes.py --checkpoint CKPT [--data data/broad] [--pybullet-data data/pybullet_test]
        [--max-sequences 400] [--out runs/unseen_bench]

Groups: the broad world's test shapes of the trained families ("in_category"), its held-out families
("held_out": manifest test_groups), and the pybullet_data meshes; plus the held-out families seen as one depth
camera's partial view with 2 mm noise ("held_out_partial", the model only: the baselines keep the whole cloud).
With whole clouds, where the checkpoint has topple fusion weights, also the fusion's topple decisions on the
same pushes (physdyn_ros.topple_fusion; its motion is the model's).
Each runs `physdyn evaluate` (roll-outs from the true initial state, 60 steps = 4 s; motion errors over the
pushes that do not topple) with the baselines: the object stays still, Coulomb sliding with the true friction,
pybullet on the cloud's convex hull with friction -20 % / +20 %. Also the centre-of-mass estimate on partial
views (models with a centre-of-mass head) against the centroid of the visible points.
Prints the tables; the last line is one JSON object {group: {method: {pos_median, pos_p90, rot_median, rot_p90,
f1, precision, recall, brier}}, "com_partial": {...}, "novelty": {group: {flagged, median}}, "novelty_examples":
{case: novelty}} (novelty: models with a topple head).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PHYSDYN = str(Path(sys.executable).parent / "physdyn")


def evaluate(ckpt: str, data: str, out: Path, categories: list[str] | None, max_sequences: int,
             baselines: list[str], partial: float = 0.0) -> dict:
    cmd = [PHYSDYN, "evaluate", "--checkpoint", ckpt, "--data", data, "--max-sequences", str(max_sequences),
           "--out", str(out), "--threads", "1", "--partial", str(partial), "--baselines", *baselines]
    if categories:
        cmd += ["--categories", *categories]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {run.stderr.strip().splitlines()[-1:]}")
    overall = json.loads((out / "metrics.json").read_text())["results"]["overall"]
    return {m: {"pos_median": r["final_pos_cm"]["median"], "pos_p90": r["final_pos_cm"]["p90"],
                "rot_median": r["final_rot_deg"]["median"], "rot_p90": r["final_rot_deg"]["p90"],
                "f1": (r.get("topple") or {}).get("f1"), "precision": (r.get("topple") or {}).get("precision"),
                "recall": (r.get("topple") or {}).get("recall"), "brier": (r.get("topple") or {}).get("brier")}
            for m, r in overall.items()}


def fusion_scores(ckpt: str, data: str, categories: list[str] | None, max_sequences: int) -> dict | None:
    """Topple F1, precision, recall, Brier of the checkpoint's topple fusion (physdyn_ros.topple_fusion: the model
    with pybullet on the whole cloud's solid) on the pushes `physdyn evaluate` scores; None without weights."""
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import topple_scores
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.topple_fusion import FusionWeights, fusion_path
    from physdyn_ros.topple_fusion_fit import model_and_truth, push_verdicts

    if not fusion_path(ckpt).is_file():
        return None
    weights = FusionWeights.load(fusion_path(ckpt))
    torch.set_num_threads(1)
    model, _ = load_model(ckpt)
    sims = load_sims(data, ["test"], categories=categories)
    index = np.arange(len(sims))
    if max_sequences < len(index):  # evaluate's choice of pushes
        index = np.linspace(0, len(sims) - 1, max_sequences).astype(np.int64)
    p_model, truth = model_and_truth(model, sims, index)
    p = weights.fuse(p_model, push_verdicts(sims, index))
    s = topple_scores(p >= 0.5, truth > 0.5)
    return {"pos_median": None, "pos_p90": None, "rot_median": None, "rot_p90": None,
            **{k: round(s[k] or 0.0, 4) for k in ("f1", "precision", "recall")},
            "brier": round(float(np.mean((p - (truth > 0.5)) ** 2)), 4)}


def com_errors(ckpt: str, data: str, categories: list[str], max_sequences: int) -> dict:
    """cm: the COM estimate's error and the visible centroid's distance from the true COM, partial views."""
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.windows import load_sims, sequences

    model, _ = load_model(ckpt)
    sims = load_sims(data, ["test"], categories=categories)
    index = np.linspace(0, len(sims) - 1, min(max_sequences, len(sims))).astype(np.int64)
    seq = sequences(sims, 1, model.cfg.num_points, index, partial=1.0, noise=0.002, view_seed=7)
    centroid = 100 * np.linalg.norm(seq["com"].numpy(), axis=-1)
    out = {"centroid_median_cm": float(np.median(centroid)), "centroid_p90_cm": float(np.percentile(centroid, 90))}
    if model.com is not None:
        with torch.inference_mode():
            est = model.com_offset(model.encode(seq["cloud"])).numpy()
        err = 100 * np.linalg.norm(est - seq["com"].numpy(), axis=-1)
        out.update(estimate_median_cm=float(np.median(err)), estimate_p90_cm=float(np.percentile(err, 90)))
    return out


def novelty_rates(ckpt: str, data: str, categories: list[str] | None, max_sequences: int,
                  partial: float = 0.0) -> dict | None:
    """Share of pushes whose novelty (models with a topple head) exceeds 1, and its median."""
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.topple_fit import topple_inputs
    from physdyn_ros.learn.windows import load_sims
    model, _ = load_model(ckpt)
    if model.topple is None:
        return None
    sims = load_sims(data, ["test"], categories=categories)
    index = np.linspace(0, len(sims) - 1, min(max_sequences, len(sims))).astype(np.int64)
    d = topple_inputs(model, sims, index, partial, view_seed=7)
    with torch.inference_mode():
        x = model.topple.raw_inputs(*(torch.from_numpy(d[k]).float() for k in ("feature", "desc", "push")))
        novelty = model.topple.novelty(x).numpy()
    return {"flagged": float(np.mean(novelty > 1)), "median": float(np.median(novelty))}


def novelty_examples(ckpt: str) -> dict | None:
    """Novelty of a few made-up pushes and shapes (the model card's examples): an ordinary box push, a faster
    push than any trained, a vertical launch, no push, a thin pole, a thin plate, a needle, a sphere."""
    import trimesh

    from physdyn_ros.predictor import Predictor
    pred = Predictor.load(ckpt)
    if pred.feature_dim == pred._dynamics_dim:  # no topple head, no novelty
        return None

    def cloud(mesh) -> np.ndarray:
        pts = np.asarray(trimesh.sample.sample_surface(mesh, 3000, seed=0)[0])
        return pts - [0.0, 0.0, pts[:, 2].min()]

    box = cloud(trimesh.creation.box(extents=(0.08, 0.06, 0.12)))
    spin = (0.0, 0.0, 0.5)
    cases = {"box, 0.5 m/s": (box, (0.5, 0, 0), spin), "box, 0.5 m/s, no spin": (box, (0.5, 0, 0), (0, 0, 0)),
             "box, no push": (box, (0, 0, 0), (0, 0, 0)), "box, 4.9 m/s": (box, (4.9, 0, 0), spin),
             "box, 1 m/s upwards": (box, (0.5, 0, 1.0), spin),
             "pole 50 x 2 cm": (cloud(trimesh.creation.cylinder(radius=0.01, height=0.5)), (0.5, 0, 0), spin),
             "plate 40 x 40 x 0.4 cm": (cloud(trimesh.creation.box(extents=(0.4, 0.4, 0.004))), (0.5, 0, 0), spin),
             "needle 50 x 1 x 1 cm": (cloud(trimesh.creation.box(extents=(0.5, 0.01, 0.01))), (0.5, 0, 0), spin),
             "sphere 5 cm": (cloud(trimesh.creation.icosphere(radius=0.05)), (0.5, 0, 0), spin)}
    return {name: round(pred.rollout(c, v, w, 60).novelty, 2) for name, (c, v, w) in cases.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--data", default="data/broad")
    parser.add_argument("--pybullet-data", default="data/pybullet_test")
    parser.add_argument("--max-sequences", type=int, default=400)
    parser.add_argument("--out", type=Path, default=Path("runs/unseen_bench"))
    args = parser.parse_args()
    manifest = json.loads((Path(args.data) / "manifest.json").read_text())
    groups = manifest.get("test_groups") or {}
    held_out, in_category = groups.get("held_out") or [], groups.get("in_category") or []
    if not held_out:
        raise SystemExit(f"{args.data} has no held-out families (manifest test_groups.held_out)")
    all_baselines = ["still", "analytic", "pybullet"]
    plan = [("in_category", args.data, in_category, all_baselines, 0.0),
            ("held_out", args.data, held_out, all_baselines, 0.0),
            ("held_out_partial", args.data, held_out, [], 1.0)]
    if Path(args.pybullet_data).is_dir():
        plan.append(("pybullet_data", args.pybullet_data, None, all_baselines, 0.0))
    result: dict = {}
    for name, data, cats, baselines, partial in plan:
        result[name] = evaluate(args.checkpoint, data, args.out / name, cats, args.max_sequences, baselines, partial)
        fused = None if partial else fusion_scores(args.checkpoint, data, cats, args.max_sequences)
        if fused is not None:  # whole clouds only: one camera's view encloses no solid
            result[name]["fusion"] = fused
        print(f"\n{name} ({args.max_sequences} sequences at most; final pose after 4 s, pushes that do not topple)")
        print(f"{'method':<18} {'pos cm med / p90':>18} {'rot deg med / p90':>19} {'topple F1 (P / R)':>19} "
              f"{'Brier':>6}")
        for m, r in result[name].items():
            f1 = "-" if r["f1"] is None else f"{r['f1']:.3f} ({r['precision'] or 0:.2f} / {r['recall'] or 0:.2f})"
            brier = "-" if r["brier"] is None else f"{r['brier']:.3f}"
            motion = "(the model's motion)".center(37) if r["pos_median"] is None else (
                f"{r['pos_median']:>8.2f} / {r['pos_p90']:<7.2f} {r['rot_median']:>8.2f} / {r['rot_p90']:<7.2f}")
            print(f"{m:<18} {motion} {f1:>19} {brier:>6}")
    result["com_partial"] = com_errors(args.checkpoint, args.data, held_out, args.max_sequences)
    novelty = {name: novelty_rates(args.checkpoint, data, cats, args.max_sequences, partial)
               for name, data, cats, _, partial in plan}
    if all(v is not None for v in novelty.values()):
        result["novelty"] = novelty
        print("\nnovelty > 1 (beyond 99.5 % of the training inputs): " + ", ".join(
            f"{name} {100 * v['flagged']:.1f} % (median {v['median']:.2f})" for name, v in novelty.items()))
        result["novelty_examples"] = novelty_examples(args.checkpoint)
        print("novelty of made-up pushes and shapes: " + ", ".join(
            f"{k} {v:.2f}" for k, v in result["novelty_examples"].items()))
    print(f"\ncentre of mass on partial views of held-out families: {result['com_partial']}")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
