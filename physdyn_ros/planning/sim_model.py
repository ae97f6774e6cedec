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
"""The planner driven by pybullet itself: candidates re-simulated with the convex hull of the observed cloud
(PybulletModel), or with the true object (ExactSimModel, the bench's ceiling).

This is the "physics engine with estimated parameters" a robotics user would plan with instead of a learned
model (docs/planning.md compares them): the geometry is the hull of the points the robot sees, the mass
distribution uniform, the friction a guess (the benchmark uses the true value off by 20 %). Same
DynamicsModel API as the Predictor, so PushPlanner runs unchanged; one candidate is one simulation, run
sequentially in one pybullet DIRECT client (pybullet is imported when the model is created, never at import).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from .. import geometry as geo
from ..conventions import DT
from ..predictor import TrajectoryBatch, check_cloud
from ..shapes.core import MassProperties, Shape, convex_hull, mass_properties

#: rad: an object that lies tilted this far at the end of a roll-out has toppled (closed_loop.observe's rule).
TILTED = math.radians(45.0)


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

    def encode(self, cloud: Any, body: Any = None) -> HullCode:
        """The hull of `cloud`, a uniform solid; with `body` (a planning PushBody), weighing as that body does
        (its mass, centre of mass and inertia: the hull collides, the body weighs)."""
        from ..shapes.core import shape_from_points

        pts = check_cloud(cloud)
        heading = float(geo.canonical_heading(pts))
        local = geo.rotate_yaw(pts - pts.mean(axis=0), -heading)
        half = 0.5 * (local.max(axis=0) - local.min(axis=0))
        if body is not None:
            com = np.asarray(body.com, dtype=np.float64)
            inertia = np.asarray(body.inertia_per_mass, dtype=np.float64)
            moments, axes = np.linalg.eigh(inertia)
            if np.linalg.det(axes) < 0:
                axes[:, 2] = -axes[:, 2]
            volume = float(body.mass) / self.config.density  # the simulated body weighs what the planner's does
            solid = MassProperties(volume=volume, mass=volume, com=np.zeros(3), inertia=inertia * volume,
                                   principal_moments=moments * volume, principal_axes=axes)
            return HullCode(shape=shape_from_points(pts - com, solid=solid), centroid=com, heading=heading,
                            half_extents=half)
        v, f = convex_hull(pts)
        com = mass_properties(v, f, density=1.0).com
        return HullCode(shape=shape_from_points(pts - com), centroid=com, heading=heading, half_extents=half)

    def rollout_batch(self, shapes: Any, lin_vels: Any, ang_vels: Any, horizon: int = 60, positions: Any = None,
                      orientations: Any = None, friction: Optional[float] = None) -> TrajectoryBatch:
        """friction: this batch's coefficient instead of the model's (planning.physics_check tries several)."""
        from ..sim import simulate_from_state

        mu = self.friction if friction is None else float(friction)
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
            rec = simulate_from_state(shapes.shape, (1.0, 1.0, 1.0), p[i], q[i], v[i], w[i], friction=mu,
                                      num_frames=int(horizon) + 1, config=self.config, sim=self._sim)
            for k in keys:
                out[k][i] = rec[k]
            topple[i] = rec["toppled"]
        return TrajectoryBatch(self.dt, out["pos"], out["quat"], out["lin_vel"], out["ang_vel"], topple)


@dataclass(frozen=True)
class ExactCode:
    """The true object at the pose it is planned from, and the hull the planner computes its pushes with."""

    mass: float  # kg, the true mass (the planner is given it: its impulses are mass x velocity)
    centroid: np.ndarray  # (3,) the true COM in the table frame (the object frame's origin)
    orientation: np.ndarray  # (4,) x, y, z, w: the true orientation
    hull_com: np.ndarray  # (3,) the COM of the observed cloud's hull (planning.body: the planner's levers)
    hull_inertia_per_mass: np.ndarray  # (3, 3) m^2, table axes


class ExactSimModel:
    """DynamicsModel by re-simulation of the true object in its own world: `truth`, the Simulator the pushes are
    executed in (the exact mesh, mass, inertia, friction and resting contacts). The bench's ceiling
    (bench/bench_planning.py's oracle): what the planner achieves when its model is the world itself.

    Each roll-out restores the world as it was when the batch began (pybullet's saveState / restoreState, which
    replay bit for bit), applies the impulse the candidate stands for and records it as the bench's execution
    does (closed_loop.execute: sim.push.record, RECORD_FRAMES frames, stopping at rest); the world is restored
    afterwards, so executing the chosen push gives exactly its roll-out. The planner hands a candidate over as
    velocities computed with its own body (the observed cloud's hull, planning.body); they are turned back into
    the impulse J = m v and the moment about the hull's COM that gave the hull's angular velocity, applied to the
    true body (the planner must be given the true mass). Roll-outs start at the true pose (`positions` and
    `orientations` are ignored); orientations come back relative to it (frame 0 = identity, as the learned
    model's). A roll-out that tipped past the topple angle or lies tilted at the end toppled (probability 1 for
    all its frames); its first `horizon` frames are returned.
    """

    #: Frames recorded per candidate (the bench's execution records as many); the roll-out stops earlier at rest.
    RECORD_FRAMES = 76

    def __init__(self, truth: Any, max_horizon: int = 150) -> None:
        self.truth = truth
        self.dt = DT
        self.max_horizon = int(max_horizon)
        self.model_id = "pybullet-exact"

    def close(self) -> None:
        """Nothing to release: the world is the caller's."""

    def __enter__(self) -> "ExactSimModel":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def encode(self, cloud: Any) -> ExactCode:
        """The true object as it lies now in `truth`; the cloud gives the hull the planner's pushes refer to."""
        pts = check_cloud(cloud)
        v, f = convex_hull(pts)
        hull = mass_properties(v, f, density=1.0)
        pos, quat, _, _ = self.truth.state()
        return ExactCode(mass=float(self.truth.mass), centroid=np.asarray(pos), orientation=np.asarray(quat),
                         hull_com=hull.com, hull_inertia_per_mass=hull.inertia / hull.mass)

    def rollout_batch(self, shapes: Any, lin_vels: Any, ang_vels: Any, horizon: int = 60, positions: Any = None,
                      orientations: Any = None) -> TrajectoryBatch:
        from ..sim.push import record

        code = shapes if isinstance(shapes, ExactCode) else self.encode(shapes)
        if isinstance(horizon, bool) or not 1 <= int(horizon) <= self.max_horizon:
            raise ValueError(f"horizon must be in 1..{self.max_horizon}, got {horizon!r}")
        v = np.atleast_2d(np.asarray(lin_vels, dtype=np.float64))
        w = np.atleast_2d(np.asarray(ang_vels, dtype=np.float64))
        b = max(len(v), len(w))
        v, w = np.broadcast_to(v, (b, 3)), np.broadcast_to(w, (b, 3))
        # the impulse the planner's push stands for: J = m v; its moment about the hull's COM is m (I/m)_hull w,
        # reached by applying J at hull COM + (J x moment) / |J|^2 (the point of the line closest to that COM)
        impulse = code.mass * v
        moment = code.mass * (w @ code.hull_inertia_per_mass.T)
        lever = np.cross(impulse, moment) / np.maximum(np.sum(impulse * impulse, axis=1), 1e-12)[:, None]
        points = code.hull_com + lever
        n = int(horizon) + 1
        frames = max(n, self.RECORD_FRAMES)
        out = {k: np.zeros((b, n, 4 if k == "quat" else 3)) for k in ("pos", "quat", "lin_vel", "ang_vel")}
        topple = np.zeros((b, n))
        q0_inv = geo.quat_inverse(code.orientation)
        sim, client = self.truth, self.truth.client
        saved = client.saveState()
        try:
            for i in range(b):
                client.restoreState(saved)
                sim.apply_impulse(impulse[i], points[i])
                rec = record(sim, frames)
                for k in ("pos", "lin_vel", "ang_vel"):
                    out[k][i] = rec[k][:n]
                out["quat"][i] = geo.quat_multiply(rec["quat"][:n].astype(np.float64),
                                                   np.broadcast_to(q0_inv, (n, 4)))
                tilted = float(geo.up_tilt_angle(rec["quat"][-1].astype(np.float64))) > TILTED
                topple[i] = float(rec["topple_index"] >= 0 or tilted)
        finally:
            client.restoreState(saved)
            client.removeState(saved)
        return TrajectoryBatch(self.dt, out["pos"], out["quat"], out["lin_vel"], out["ang_vel"], topple)
