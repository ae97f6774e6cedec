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
"""Closed-loop pushing in the pybullet Simulator: plan, push, observe, re-plan until within tolerance.

    with Simulator(SimConfig(collision="hull")) as sim:
        sim.spawn(shape, scale, xy=(0, 0), yaw=0.3)
        result = push_to_goal(sim, planner, Goal(Pose2D(0.2, 0.1, 0.8)), max_pushes=3, mass=sim.mass)

Observation is what a perfect depth tracker would give: the object's pose from the simulator and its cloud
(the shape's surface samples, scaled, posed at the observed pose; with `view`, only those a camera far away in that
direction sees, as one depth camera's cloud). pybullet is needed only because a Simulator is passed in; this
module imports nothing from it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from .. import geometry as geo
from ..conventions import REST_ANG_VEL, REST_FRAMES, REST_LIN_VEL
from .planner import PushPlanner
from .session import PushSession, goal_errors
from .types import Goal, PlannerConfig, PlanningError, Pose2D, PushPlan, yaw_of

#: Execution modes: apply the planned impulse at the contact point, or set the planned velocities directly.
EXECUTE_MODES = ("impulse", "velocity")


@dataclass(frozen=True)
class Observation:
    pose: Pose2D
    position: np.ndarray  # (3,) COM
    orientation: np.ndarray  # (4,) x, y, z, w
    cloud: np.ndarray  # (N, 3) table frame
    toppled: bool


@dataclass(frozen=True)
class PushOutcome:
    plan: PushPlan
    final_pose: Pose2D  # where the object really stopped
    position_error: float  # m, real final distance to the goal
    yaw_error: float  # rad (0 when the goal ignores yaw)
    toppled: bool
    frames: int  # recorded frames until rest


@dataclass
class ClosedLoopResult:
    success: bool  # within tolerance, upright, after at most max_pushes
    outcome: str = ""  # planning.session.OUTCOMES: reached, refused, toppled, out_of_pushes
    pushes: list[PushOutcome] = field(default_factory=list)
    final_pose: Optional[Pose2D] = None
    position_error: float = math.inf
    yaw_error: float = math.inf
    message: str = ""
    goal: Optional[Goal] = None  # the episode's goal, with the yaw symmetry its errors were folded by

    @property
    def planning_times(self) -> list[float]:
        return [p.plan.planning_time for p in self.pushes]


def observe(sim: Any, cloud_noise: float = 0.0, rng: Optional[np.random.Generator] = None,
            view: Optional[np.ndarray] = None) -> Observation:
    """The object's pose and cloud as seen now (cloud_noise: std of Gaussian noise on the points, m; view: (3,)
    the direction from the object towards a camera far away, table frame: only the points it sees)."""
    pos, quat, _, _ = sim.state()
    pts = np.asarray(sim.shape.points, dtype=np.float64) * np.asarray(sim.scale)
    cloud = geo.quat_rotate(np.broadcast_to(quat, (len(pts), 4)), pts) + pos
    if view is not None:
        from ..learn.views import visible

        cloud = cloud[visible(cloud[None], np.asarray(view, dtype=np.float64)[None])[0]]
    if cloud_noise > 0:
        cloud = cloud + (rng or np.random.default_rng()).normal(0.0, cloud_noise, cloud.shape)
    tilt = float(geo.up_tilt_angle(quat))
    return Observation(Pose2D(float(pos[0]), float(pos[1]), float(yaw_of(quat))), np.asarray(pos), np.asarray(quat),
                       cloud, tilt > math.radians(45.0))


def execute(sim: Any, plan: PushPlan, mode: str = "impulse", num_frames: int = 76) -> dict[str, np.ndarray]:
    """Apply a plan in the simulator and record until the object rests (sim.push.record's arrays)."""
    from ..sim.push import record  # the simulator core (pybullet); the caller already has a Simulator

    if mode == "impulse":
        sim.apply_impulse(plan.impulse, plan.contact_point)
    elif mode == "velocity":
        sim.set_velocity(plan.lin_vel, plan.ang_vel)
    else:
        raise ValueError(f"execute mode must be one of {EXECUTE_MODES}, got {mode!r}")
    rec = record(sim, num_frames)
    settle(sim)
    return rec


def settle(sim: Any, max_frames: int = 450) -> bool:
    """Step the simulator until the object rests (conventions.REST_*; at most max_frames, 30 s): a push still
    moving at the end of its recording must not be observed mid-motion. True if it came to rest."""
    quiet = 0
    for _ in range(max_frames):
        _, _, v, w = sim.state()
        quiet = quiet + 1 if (np.linalg.norm(v) < REST_LIN_VEL and np.linalg.norm(w) < REST_ANG_VEL) else 0
        if quiet >= REST_FRAMES:
            return True
        sim.step_frame()
    return False


def push_to_goal(sim: Any, planner: PushPlanner, goal: Goal, max_pushes: int = 3, mass: Optional[float] = None,
                 mode: str = "impulse", config: Optional[PlannerConfig] = None, cloud_noise: float = 0.0,
                 rng: Optional[np.random.Generator] = None, num_frames: int = 76, adapt: bool = True,
                 view: Optional[np.ndarray] = None) -> ClosedLoopResult:
    """Push the simulator's object towards `goal`, re-planning from where it stopped, up to max_pushes pushes.

    The episode's rules are planning.session.PushSession's (the `push_to_goal` action uses the same): stops when
    within tolerance, when the object toppled, when the planner refuses, or out of pushes; `result.outcome`
    says which. The yaw goal is folded by the symmetry of the first observed cloud (PushSession.observe_shape)
    unless the goal gives its yaw_symmetry or the config's detect_symmetry is off. `mass` is the mass used for
    impulses (default: the planner's estimate); `adapt` aims each push by the observed / predicted slide ratio of
    the pushes before it; `view`: the clouds are one camera's, looking from that direction (observe).
    """
    session = PushSession(goal, max_pushes, adapt=adapt)
    result = ClosedLoopResult(success=False)
    obs = observe(sim, cloud_noise, rng, view)
    if (config or planner.config).detect_symmetry:
        session.observe_shape(obs.cloud)  # the yaw the first cloud shows: the planner's, the stops' and the result's
    goal = session.goal
    while (stop := session.check(obs.pose, obs.toppled)) is None:
        try:
            cfg = config or planner.config
            aim = session.aim(obs.pose, cfg.table, cfg.reach())
            plan = planner.plan(obs.cloud, obs.pose, aim, mass=mass, config=config)
        except PlanningError as exc:
            stop = session.refused(str(exc))
            break
        rec = execute(sim, plan, mode, num_frames)
        start, obs = obs.pose, observe(sim, cloud_noise, rng, view)
        toppled = bool(rec["topple_index"] >= 0) or obs.toppled
        step = session.record(start, plan.final_pose, obs.pose, toppled)
        result.pushes.append(PushOutcome(plan, obs.pose, step.position_error, step.yaw_error, toppled,
                                         int(rec["length"])))
    result.final_pose, result.goal = obs.pose, goal
    result.position_error, result.yaw_error = goal_errors(obs.pose, goal)
    result.success, result.outcome, result.message = stop.success, stop.outcome, stop.message
    return result
