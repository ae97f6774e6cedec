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
"""The planner's physics check: its finalists re-simulated in pybullet on the observed cloud's convex hull.

Why: on shapes unlike those it was trained on, the learned topple head misses topples that physics on the hull
catches (held-out families, 3,000 pushes: the model finds 80 % of the topples, the hull at friction -20 % / +20 % 97 %
/ 98 %; bench/topple_mix.py), while the hull cries topple where the real object would not (precision 0.76-0.79: it
knows neither the true mass distribution nor the friction). So the hull vetoes rather than decides: a push is safe
when both the learned model and the hull say so. Each finalist is simulated at the nominal friction and at
friction_error more (sliding friction tips an object forward over its leading edge), and its most toppling
perturbation of the robustness check at the nominal; the share of those runs that toppled is the push's physics
topple probability, the plan's `physics_topple_probability`.

The share is held to the planner's max_topple_probability: at the default 0.35 one toppled run of three (the
higher friction or the perturbation only) passes, two veto; a push checked without a perturbation (two runs) is
vetoed by one.

With a whole cloud and the model's topple fusion weights (physdyn_ros.topple_fusion: fitted on pushes of new
shapes, the hull weighing as the cloud's solid, the push at 20 % less and more friction and 10 % slower and
faster), the verdict is instead the fused probability of the model's whole-push probability and those runs
(`fused_topple`): better calibrated on held-out families than either (Brier 0.020 against the hull's 0.044). A
push that tips the solid in most runs is vetoed whatever the model says: the weights were fitted on random pushes,
while a planner seeks out exactly the pushes the model calls safe (bench/bench_planning.py, 84 trials of a fixed
search: the fusion alone let 7 objects topple, the share of toppled runs 3, the fusion with this veto 3, with as
many refusals and 40 % less planning time).

One run costs about 5 ms (a 1-2 s roll-out that stops at rest); the planner checks its finalists in the order it
prefers them and stops at the first safe one (planning/search.py: Search.robust).
"""
from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from ..topple_fusion import FUSION_FRAMES, FusionWeights
from .body import PushBody
from .sim_model import HullCode, PybulletModel

__all__ = ["PhysicsCheck", "PHYSICS_FRAMES"]

#: Frames (1/15 s) simulated at least: a tip that starts slowly has passed the topple angle within 2 s.
PHYSICS_FRAMES = 30


class PhysicsCheck:
    """Topple share of pushes re-simulated on the hull of a cloud (pybullet DIRECT; imported on creation)."""

    def __init__(self, friction: float = 0.5, friction_error: float = 0.2, config: Any = None,
                 fusion: Optional[FusionWeights] = None) -> None:
        if not 0.0 <= friction_error < 1.0:
            raise ValueError(f"friction_error must be in [0, 1), got {friction_error}")
        self.model = PybulletModel(friction, config)
        self.friction = float(friction)
        self.frictions = (friction * (1.0 - friction_error), friction * (1.0 + friction_error))
        self.fusion = fusion  # the model's topple fusion weights (fused_topple), or None

    def close(self) -> None:
        self.model.close()

    def __enter__(self) -> "PhysicsCheck":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def encode(self, points: np.ndarray, body: Optional[PushBody] = None) -> HullCode:
        """The hull of `points` (N, 3), table frame, as observed at the start pose; with `body`, weighing as the
        planner's body does (its centre of mass and inertia: the pushes' velocities refer to them)."""
        return self.model.encode(points, body)

    def topple_share(self, code: HullCode, nominal: Sequence[np.ndarray], perturbed: Optional[Sequence[np.ndarray]],
                     horizon: int, limit: float = 1.0) -> float:
        """Share of toppled runs: the nominal push (lin_vel, ang_vel) at the higher and the nominal friction and,
        when given, the perturbed one at the nominal. Velocities are the table frame's; the runs start at the
        hull's COM. The runs stop once the share exceeds `limit` whatever the rest do (the share so far)."""
        frames = max(int(horizon), PHYSICS_FRAMES)
        runs = [(nominal, self.frictions[1]), (nominal, self.friction)]
        if perturbed is not None:
            runs.append((perturbed, self.friction))
        toppled = 0
        for (v, w), mu in runs:
            batch = self.model.rollout_batch(code, np.asarray(v)[None], np.asarray(w)[None], horizon=frames,
                                             friction=mu)
            toppled += int(batch.topple_prob[0].max() > 0.5)
            if toppled / len(runs) > limit:
                break
        return toppled / len(runs)

    def fused_topple(self, code: HullCode, nominal: Sequence[np.ndarray], p_model: float, horizon: int) -> float:
        """The topple fusion's probability of the nominal push (lin_vel, ang_vel, table frame, from the hull's
        COM): the model's whole-push probability `p_model` and the fusion's runs (code: the hull weighing as the
        whole cloud's solid, as the fusion was fitted); 1 when most runs toppled."""
        if self.fusion is None:
            raise RuntimeError("this physics check has no topple fusion weights")
        frames = max(int(horizon), FUSION_FRAMES)
        runs = len(self.fusion.runs)
        toppled = np.zeros(runs)
        v, w = np.asarray(nominal[0], dtype=np.float64), np.asarray(nominal[1], dtype=np.float64)
        for i, (fm, fs) in enumerate(self.fusion.runs):
            batch = self.model.rollout_batch(code, v[None] * fs, w[None] * fs, horizon=frames,
                                             friction=self.friction * fm)
            toppled[i] = float(batch.topple_prob[0].max() > 0.5)
            if toppled.sum() > 0.5 * runs:  # most runs toppled: vetoed, whatever the rest do
                return 1.0
        return float(self.fusion.fuse(np.array([p_model]), toppled[None])[0])
