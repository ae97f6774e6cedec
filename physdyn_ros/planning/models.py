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
"""Dynamics models the push planner can drive (numpy; no rclpy, no pybullet).

The planner needs only the part of the Predictor API that a sampling optimiser uses (`DynamicsModel`):
`encode(cloud)` once per object and `rollout_batch(code, lin_vels, ang_vels, horizon, positions,
orientations) -> TrajectoryBatch`. Three implementations exist:

* physdyn_ros.predictor.Predictor: the learned model (the planner's purpose);
* AnalyticSlidingModel (here): the closed-form Coulomb sliding + spin-decay baseline of
  physdyn_ros.learn.baselines, behind the same API. A physics stand-in with no training, used where no
  trained model exists (tests) and as a sanity reference;
* physdyn_ros.planning.sim_model.PybulletModel: re-simulation of the cloud's convex hull in pybullet (the
  "engine with estimated parameters" comparison of bench/bench_planning.py).
"""
from __future__ import annotations

from typing import Any, Protocol, Sequence, Union

import numpy as np

from .. import geometry as geo
from ..conventions import DT
from ..learn.baselines import analytic_sliding, horizontal_radius
from ..predictor import ShapeCode, Trajectory, TrajectoryBatch, check_cloud


class DynamicsModel(Protocol):
    """What the planner calls. `encode` returns a code with a `centroid` (3,) attribute (start height)."""

    model_id: str
    dt: float
    max_horizon: int

    def encode(self, cloud: Any) -> Any: ...

    def rollout_batch(self, shapes: Any, lin_vels: Any, ang_vels: Any, horizon: int = 60, positions: Any = None,
                      orientations: Any = None) -> TrajectoryBatch: ...


class AnalyticSlidingModel:
    """Closed-form sliding physics behind the Predictor's batch API (deterministic, never topples).

    The COM decelerates at mu g along its initial horizontal velocity and the spin about z decays at
    mu g / r (r: RMS horizontal radius of the cloud, stored as the code's one-number feature); tilt rates are
    dropped. Exact for a flat-bottomed block sliding without spin; spin and sliding are treated as independent
    (in reality each speeds up the other's decay), so it is a physics stand-in, not ground truth.
    """

    def __init__(self, friction: float = 0.5, dt: float = DT, max_horizon: int = 150) -> None:
        if not 0 < friction <= 10:
            raise ValueError(f"friction must be in (0, 10], got {friction}")
        self.friction = float(friction)
        self.dt = float(dt)
        self.max_horizon = int(max_horizon)
        self.model_id = f"analytic-sliding-mu{self.friction:g}"

    def encode(self, cloud: Any) -> ShapeCode:
        pts = check_cloud(cloud)
        heading = float(geo.canonical_heading(pts))
        centroid = pts.mean(axis=0)
        local = geo.rotate_yaw(pts - centroid, -heading)
        radius = float(horizontal_radius(pts[None])[0])
        return ShapeCode(feature=np.array([radius], dtype=np.float32), heading=heading, centroid=centroid,
                         half_extents=0.5 * (local.max(axis=0) - local.min(axis=0)), num_points=len(pts),
                         model_id=self.model_id)

    def _code(self, shape: Union[ShapeCode, np.ndarray]) -> ShapeCode:
        if isinstance(shape, ShapeCode):
            if shape.model_id and shape.model_id != self.model_id:
                raise ValueError(f"shape code was encoded by model {shape.model_id}, this model is {self.model_id}")
            return shape
        return self.encode(shape)

    def rollout_batch(self, shapes: Union[ShapeCode, np.ndarray, Sequence[Any]], lin_vels: Any, ang_vels: Any,
                      horizon: int = 60, positions: Any = None, orientations: Any = None) -> TrajectoryBatch:
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or \
                not 1 <= int(horizon) <= self.max_horizon:
            raise ValueError(f"horizon must be an integer in 1..{self.max_horizon}, got {horizon!r}")
        codes = [self._code(s) for s in shapes] if isinstance(shapes, (list, tuple)) else \
            [self._code(shapes)]  # type: ignore[arg-type]  # a single code or cloud
        v = np.atleast_2d(np.asarray(lin_vels, dtype=np.float64))
        w = np.atleast_2d(np.asarray(ang_vels, dtype=np.float64))
        b = max(len(codes), len(v), len(w))
        if {len(codes), len(v), len(w)} - {1, b} or v.shape[1:] != (3,) or w.shape[1:] != (3,):
            raise ValueError("lin_vels / ang_vels must be (B, 3) or (3,) and agree with the number of shapes")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise ValueError("velocities contain NaN or inf")
        radius = np.array([float(c.feature[0]) for c in codes])
        centroids = np.stack([c.centroid for c in codes])
        p = np.broadcast_to(centroids if positions is None else np.atleast_2d(np.asarray(positions, float)), (b, 3))
        q = np.broadcast_to(np.array([[0.0, 0.0, 0.0, 1.0]]) if orientations is None
                            else geo.quat_normalize(np.atleast_2d(np.asarray(orientations, float))), (b, 4))
        out = analytic_sliding(p, q, np.broadcast_to(v, (b, 3)), np.broadcast_to(w, (b, 3)),
                               np.full(b, self.friction), np.broadcast_to(radius, (b,)), int(horizon), self.dt)
        return TrajectoryBatch(self.dt, out["pos"], out["quat"], out["lin_vel"], out["ang_vel"],
                               np.zeros((b, int(horizon) + 1)))

    def rollout(self, shape: Union[ShapeCode, np.ndarray], lin_vel: Any, ang_vel: Any, horizon: int = 60,
                position: Any = None, orientation: Any = None) -> Trajectory:
        return self.rollout_batch(shape, lin_vel, ang_vel, horizon, position, orientation)[0]
