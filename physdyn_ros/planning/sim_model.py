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
"""The planner driven by pybullet itself: candidates re-simulated with the convex hull of the observed cloud.

This is the "physics engine with estimated parameters" a robotics user would plan with instead of a learned
model (docs/planning.md compares them): the geometry is the hull of the points the robot sees, the mass
distribution uniform, the friction a guess (the benchmark uses the true value off by 20 %). Same
DynamicsModel API as the Predictor, so PushPlanner runs unchanged; one candidate is one simulation, run
sequentially in one pybullet DIRECT client (pybullet is imported when the model is created, never at import).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .. import geometry as geo
from ..conventions import DT
from ..predictor import TrajectoryBatch, check_cloud
from ..shapes.core import Shape, convex_hull, mass_properties


@dataclass(frozen=True)
class HullCode:
    """The simulated object: the cloud's solid convex hull, points relative to the hull's centre of mass."""

    shape: Shape  # hull of the cloud, object frame = table axes at the observed pose, origin = COM
    centroid: np.ndarray  # (3,) the COM in the table frame (roll-outs start here by default)
    heading: float  # canonical heading of the cloud (for callers that want the ShapeCode fields)
    half_extents: np.ndarray  # (3,)


class PybulletModel:
    """DynamicsModel by re-simulation. friction: the effective Coulomb coefficient assumed for the object."""

    def __init__(self, friction: float = 0.5, config: Any = None, max_horizon: int = 150) -> None:
        from ..sim import SimConfig, Simulator  # pybullet: only this baseline needs it

        if not 0 < friction <= 10:
            raise ValueError(f"friction must be in (0, 10], got {friction}")
        self.friction = float(friction)
        # hull collisions are exact for a lone object on a plane; the sim's rest rules end short roll-outs early
        self.config = config if config is not None else SimConfig(collision="hull")
        self.dt = DT
        self.max_horizon = int(max_horizon)
        self.model_id = f"pybullet-hull-mu{self.friction:g}"
        self._sim: Optional[Any] = Simulator(self.config)

    def close(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    def __enter__(self) -> "PybulletModel":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def encode(self, cloud: Any) -> HullCode:
        from ..shapes.core import shape_from_points

        pts = check_cloud(cloud)
        v, f = convex_hull(pts)
        com = mass_properties(v, f, density=1.0).com
        heading = float(geo.canonical_heading(pts))
        local = geo.rotate_yaw(pts - pts.mean(axis=0), -heading)
        return HullCode(shape=shape_from_points(pts - com), centroid=com, heading=heading,
                        half_extents=0.5 * (local.max(axis=0) - local.min(axis=0)))

    def rollout_batch(self, shapes: Any, lin_vels: Any, ang_vels: Any, horizon: int = 60, positions: Any = None,
                      orientations: Any = None) -> TrajectoryBatch:
        from ..sim import simulate_from_state

        if self._sim is None:
            raise RuntimeError("PybulletModel is closed")
        if not isinstance(shapes, HullCode):
            shapes = self.encode(shapes)
        if isinstance(horizon, bool) or not 1 <= int(horizon) <= self.max_horizon:
            raise ValueError(f"horizon must be in 1..{self.max_horizon}, got {horizon!r}")
        v = np.atleast_2d(np.asarray(lin_vels, dtype=np.float64))
        w = np.atleast_2d(np.asarray(ang_vels, dtype=np.float64))
        b = max(len(v), len(w))
        p = np.broadcast_to(shapes.centroid if positions is None else np.atleast_2d(np.asarray(positions, float)),
                            (b, 3))
        q = np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0]) if orientations is None
                            else np.atleast_2d(np.asarray(orientations, float)), (b, 4))
        v, w = np.broadcast_to(v, (b, 3)), np.broadcast_to(w, (b, 3))
        keys = ("pos", "quat", "lin_vel", "ang_vel")
        out = {k: np.zeros((b, int(horizon) + 1, 4 if k == "quat" else 3)) for k in keys}
        topple = np.zeros((b, int(horizon) + 1))
        for i in range(b):
            rec = simulate_from_state(shapes.shape, (1.0, 1.0, 1.0), p[i], q[i], v[i], w[i], friction=self.friction,
                                      num_frames=int(horizon) + 1, config=self.config, sim=self._sim)
            for k in keys:
                out[k][i] = rec[k]
            topple[i] = rec["toppled"]
        return TrajectoryBatch(self.dt, out["pos"], out["quat"], out["lin_vel"], out["ang_vel"], topple)
