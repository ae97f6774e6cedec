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
"""`physdyn fit-topple-fusion`: fit a checkpoint's topple fusion (physdyn_ros.topple_fusion) on a dataset.

    physdyn fit-topple-fusion --data data/fit_families [--checkpoint CKPT] [--splits test] [--max-sequences 1500]
        [--out PATH]

For each push (evenly spaced over the splits): the model's whole-push topple probability from the true initial
state and the whole cloud (what `physdyn evaluate` scores), and the solid hull's pybullet runs (RUNS); then the
logistic regression on whether the push toppled. Fit on shapes the fusion is not measured on (the model card's
run: new shapes of the trained families; bench/topple_mix.py measures it on held-out families). Writes the
weights beside the checkpoint (`<checkpoint>.topple_fusion.json`, atomically) unless --out says otherwise.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from .fit_args import add_fit_arguments, fit_pushes
from .topple_fusion import FUSION_FRAMES, RUNS, FusionWeights, SolidPhysics, fit_weights, fusion_path

__all__ = ["push_verdicts", "add_arguments", "run"]


def push_verdicts(sims: Any, index: np.ndarray) -> np.ndarray:
    """(B, R) the solid hull's pybullet verdicts (SolidPhysics.toppled) on a dataset's pushes `index`: the whole
    canonical cloud at its start pose, the true initial velocities about the true centre of mass, the push's
    friction as the nominal."""
    from .geometry import quat_rotate

    out = np.zeros((len(index), len(RUNS)))
    with SolidPhysics(0.5, RUNS) as physics:
        for j, i in enumerate(index):
            pts = sims.points[sims.shape_index[i]].astype(np.float64) * sims.scale[i].astype(np.float64)
            q = np.broadcast_to(sims.quat[i, 0].astype(np.float64), pts.shape[:1] + (4,))
            pos = sims.pos[i, 0].astype(np.float64)
            out[j] = physics.toppled(quat_rotate(q, pts) + pos, pos, sims.lin_vel[i, 0], sims.ang_vel[i, 0],
                                     friction=float(sims.friction[i]))
    return out


def model_and_truth(model: Any, sims: Any, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model's whole-push probabilities (B,) over FUSION_FRAMES from the true initial states and whole
    clouds, and whether each push toppled (B,)."""
    import torch

    from .learn.evaluate import ground_truth, model_rollouts

    with torch.inference_mode():
        rolled = model_rollouts(model, sims, index, FUSION_FRAMES).topple_prob
    truth = ground_truth(sims, index, FUSION_FRAMES).topple_prob
    assert rolled is not None and truth is not None  # a model with a topple head, a dataset with labels
    return rolled.max(axis=1), truth.max(axis=1)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_fit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import torch

    from .learn.checkpoint import load_model
    from .learn.evaluate import topple_scores

    torch.set_num_threads(1)
    ckpt, sims, index = fit_pushes(args, 10)
    model, meta = load_model(ckpt)
    if model.topple is None:
        raise ValueError(f"{ckpt} has no whole-push topple head: fit one first (physdyn fit-topple)")
    p_model, truth = model_and_truth(model, sims, index)
    toppled = push_verdicts(sims, index)
    coef, bias = fit_weights(p_model, toppled, truth)
    weights = FusionWeights(model_id=str(meta["model_id"]), model=float(coef[0]),
                            physics=tuple(float(c) for c in coef[1:]), bias=bias, runs=RUNS,
                            fitted_on=f"{Path(args.data).name} ({', '.join(args.splits)})", pushes=len(index))
    fused = weights.fuse(p_model, toppled)
    for name, p in (("model", p_model), ("fusion (in-sample)", fused)):
        f1 = topple_scores(p >= 0.5, truth > 0.5)["f1"] or 0.0
        print(f"{name:<20} F1 {f1:.3f}  Brier {float(np.mean((p - (truth > 0.5)) ** 2)):.4f}")
    out = args.out or fusion_path(ckpt)
    weights.save(out)
    print(f"{len(index)} pushes ({int((truth > 0.5).sum())} toppled): weights {np.round(coef, 3).tolist()}, bias "
          f"{bias:.3f} -> {out}")
    return 0
