"""Closed-loop pushing in the pybullet Simulator: plan, push, observe, re-plan until within tolerance.

    with Simulator(SimConfig(collision="hull")) as sim:
        sim.spawn(shape, scale, xy=(0, 0), yaw=0.3)
        result = push_to_goal(sim, planner, Goal(Pose2D(0.2, 0.1, 0.8)), max_pushes=3, mass=sim.mass)

Observation is what a perfect depth tracker would give: the object's pose from the simulator and its cloud
(the shape's surface samples, scaled, posed at the observed pose). pybullet is needed only because a
Simulator is passed in; this module imports nothing from it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from .. import geometry as geo
from .planner import Goal, PlannerConfig, PlanningError, Pose2D, PushPlan, PushPlanner, wrap_angle, yaw_of

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
    pushes: list[PushOutcome] = field(default_factory=list)
    final_pose: Optional[Pose2D] = None
    position_error: float = math.inf
    yaw_error: float = math.inf
    message: str = ""

    @property
    def planning_times(self) -> list[float]:
        return [p.plan.planning_time for p in self.pushes]


def observe(sim: Any, cloud_noise: float = 0.0, rng: Optional[np.random.Generator] = None) -> Observation:
    """The object's pose and cloud as seen now (cloud_noise: std of Gaussian noise on the points, m)."""
    pos, quat, _, _ = sim.state()
    pts = np.asarray(sim.shape.points, dtype=np.float64) * np.asarray(sim.scale)
    cloud = geo.quat_rotate(np.broadcast_to(quat, (len(pts), 4)), pts) + pos
    if cloud_noise > 0:
        cloud = cloud + (rng or np.random.default_rng()).normal(0.0, cloud_noise, cloud.shape)
    tilt = float(geo.up_tilt_angle(quat))
    return Observation(Pose2D(float(pos[0]), float(pos[1]), float(yaw_of(quat))), np.asarray(pos), np.asarray(quat),
                       cloud, tilt > math.radians(45.0))


def errors(pose: Pose2D, goal: Goal) -> tuple[float, float]:
    pos_err = float(np.linalg.norm(pose.xy - goal.pose.xy))
    yaw_err = 0.0 if goal.ignores_yaw else abs(float(wrap_angle(pose.yaw - goal.pose.yaw)))
    return pos_err, yaw_err


def execute(sim: Any, plan: PushPlan, mode: str = "impulse", num_frames: int = 76) -> dict[str, np.ndarray]:
    """Apply a plan in the simulator and record until the object rests (sim.push.record's arrays)."""
    from ..sim.push import record  # the simulator core (pybullet); the caller already has a Simulator

    if mode == "impulse":
        sim.apply_impulse(plan.impulse, plan.contact_point)
    elif mode == "velocity":
        sim.set_velocity(plan.lin_vel, plan.ang_vel)
    else:
        raise ValueError(f"execute mode must be one of {EXECUTE_MODES}, got {mode!r}")
    return record(sim, num_frames)


def push_to_goal(sim: Any, planner: PushPlanner, goal: Goal, max_pushes: int = 3, mass: Optional[float] = None,
                 mode: str = "impulse", config: Optional[PlannerConfig] = None, cloud_noise: float = 0.0,
                 rng: Optional[np.random.Generator] = None, num_frames: int = 76) -> ClosedLoopResult:
    """Push the simulator's object towards `goal`, re-planning from where it stopped, up to max_pushes pushes.

    Stops early when within tolerance, when the object toppled, or when the planner refuses (the reason is
    in the result's message). `mass` is the mass used for impulses (default: the planner's estimate).
    """
    if max_pushes < 1:
        raise ValueError(f"max_pushes must be >= 1, got {max_pushes}")
    result = ClosedLoopResult(success=False)
    obs = observe(sim, cloud_noise, rng)
    for k in range(max_pushes):
        result.final_pose = obs.pose
        result.position_error, result.yaw_error = errors(obs.pose, goal)
        if obs.toppled:
            result.message = f"object toppled after push {k}"
            return result
        within = result.position_error <= goal.position_tolerance and (
            goal.ignores_yaw or result.yaw_error <= goal.yaw_tolerance)
        if within:
            result.success = True
            result.message = f"within tolerance after {k} push(es)"
            return result
        try:
            plan = planner.plan(obs.cloud, obs.pose, goal, mass=mass, config=config)
        except PlanningError as exc:
            result.message = f"push {k + 1}: {exc}"
            return result
        rec = execute(sim, plan, mode, num_frames)
        obs = observe(sim, cloud_noise, rng)
        pos_err, yaw_err = errors(obs.pose, goal)
        result.pushes.append(PushOutcome(plan, obs.pose, pos_err, yaw_err, bool(rec["topple_index"] >= 0),
                                         int(rec["length"])))
    result.final_pose = obs.pose
    result.position_error, result.yaw_error = errors(obs.pose, goal)
    result.success = (not obs.toppled and result.position_error <= goal.position_tolerance
                      and (goal.ignores_yaw or result.yaw_error <= goal.yaw_tolerance))
    result.message = (f"{'within' if result.success else 'outside'} tolerance after {len(result.pushes)} push(es): "
                      f"{100 * result.position_error:.1f} cm, {math.degrees(result.yaw_error):.1f} deg"
                      + (" (toppled)" if obs.toppled else ""))
    return result
