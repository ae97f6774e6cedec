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
"""The planner's value types: poses, goals, the table, the planner's parameters and the plan it returns.

Every constructor checks its numbers (finite, positive where it must be) and raises PlanningError, a ValueError
with the reason, so a bad request is refused before any search runs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional, Union

import numpy as np

from ..conventions import GRAVITY
from ..geometry import yaw_of
from ..predictor import Trajectory
from ..shapes.core import DEFAULT_DENSITY

__all__ = ["Goal", "PlannerConfig", "PlanningError", "Pose2D", "PushPlan", "TableBounds", "finite", "fold_yaw",
           "wrap_angle", "yaw_of"]


class PlanningError(ValueError):
    """The request cannot be planned; the message says why (bad input, unreachable goal, every push topples)."""


def wrap_angle(a: Union[float, np.ndarray]) -> Union[float, np.ndarray]:
    """Angle(s) wrapped into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi if isinstance(a, np.ndarray) else \
        (float(a) + math.pi) % (2 * math.pi) - math.pi


def fold_yaw(error: Union[float, np.ndarray], order: Optional[int]) -> Union[float, np.ndarray]:
    """Yaw error(s) in [0, pi] (|wrapped|) under a k-fold symmetry about the up axis: the distance to the nearest
    multiple of 2 pi / k; 0 for order 0 (continuous symmetry); unchanged, bit for bit, for order None or 1 and
    wherever it is at most pi / k (planning.symmetry decides the order from a cloud)."""
    if order is None or order == 1:
        return error
    if order == 0:
        return np.zeros_like(error) if isinstance(error, np.ndarray) else 0.0
    period = 2.0 * math.pi / order
    if isinstance(error, np.ndarray):
        r = np.mod(error, period)
        return np.minimum(r, period - r)
    r = float(error) % period
    return min(r, period - r)


def finite(value: Any, name: str) -> float:
    """`value` as a float; PlanningError naming `name` if it is not a finite number."""
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise PlanningError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(f):
        raise PlanningError(f"{name} is not finite ({f})")
    return f


@dataclass(frozen=True)
class Pose2D:
    """A pose on the table: x, y of the centre of mass (m, table frame) and yaw (rad) of the object."""

    x: float
    y: float
    yaw: float

    def __post_init__(self) -> None:
        for name in ("x", "y", "yaw"):
            object.__setattr__(self, name, finite(getattr(self, name), f"pose {name}"))

    @classmethod
    def of(cls, value: Union["Pose2D", Any], name: str = "pose") -> "Pose2D":
        """A Pose2D from a Pose2D or three numbers (x, y, yaw)."""
        if isinstance(value, Pose2D):
            return value
        try:
            x, y, yaw = (float(v) for v in value)
        except (TypeError, ValueError):
            raise PlanningError(f"{name} must be (x, y, yaw), got {value!r}") from None
        try:
            return cls(x, y, yaw)
        except PlanningError as exc:
            raise PlanningError(f"{name}: {exc}") from None

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])


@dataclass(frozen=True)
class Goal:
    """Where the object should come to rest. yaw_tolerance >= pi means any yaw is fine.

    yaw_symmetry: the order of the object's rotational symmetry about its up axis (planning.symmetry): 1 none,
    k >= 2 the yaw counts modulo 2 pi / k, 0 any yaw is fine (an upright cylinder); None: not known yet (the
    planner finds it from the cloud, PushSession.observe_shape for an episode; taken as 1 until then).
    """

    pose: Pose2D
    position_tolerance: float = 0.02  # m
    yaw_tolerance: float = math.radians(10.0)  # rad
    yaw_symmetry: Optional[int] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", Pose2D.of(self.pose, "goal pose"))
        for name in ("position_tolerance", "yaw_tolerance"):
            v = finite(getattr(self, name), name)
            if v <= 0:
                raise PlanningError(f"{name} must be positive, got {v}")
            object.__setattr__(self, name, v)
        k = self.yaw_symmetry
        if k is not None:
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
                raise PlanningError(f"yaw_symmetry must be None or an integer >= 0, got {k!r}")
            object.__setattr__(self, "yaw_symmetry", int(k))

    @property
    def ignores_yaw(self) -> bool:
        """Any yaw is within tolerance: the tolerance covers a half turn, or the symmetry's half period."""
        k = self.yaw_symmetry
        if k == 0:
            return True
        return self.yaw_tolerance >= (math.pi / k if k is not None and k >= 2 else math.pi)

    def yaw_error(self, yaw: Union[float, np.ndarray]) -> Union[float, np.ndarray]:
        """|yaw - goal yaw| (rad, [0, pi]) of final yaw(s), folded by the symmetry (fold_yaw)."""
        if isinstance(yaw, np.ndarray):
            return fold_yaw(np.abs(wrap_angle(yaw - self.pose.yaw)), self.yaw_symmetry)
        return fold_yaw(abs(float(wrap_angle(float(yaw) - self.pose.yaw))), self.yaw_symmetry)

    def turn_from(self, yaw: float) -> float:
        """Signed turn (rad) from `yaw` to the nearest yaw the symmetry makes equal to the goal's (the plain
        wrapped difference, bit for bit, without symmetry or when it is within half a period)."""
        turn = float(wrap_angle(self.pose.yaw - float(yaw)))
        k = self.yaw_symmetry
        if k is None or k <= 1:
            return turn
        period = 2.0 * math.pi / k
        return turn - period * round(turn / period)


@dataclass(frozen=True)
class TableBounds:
    """Axis-aligned table top (m, table frame); the COM must stay inside."""

    x_min: float = -1.0
    x_max: float = 1.0
    y_min: float = -1.0
    y_max: float = 1.0

    def __post_init__(self) -> None:
        vals = [finite(getattr(self, k), f"table {k}") for k in ("x_min", "x_max", "y_min", "y_max")]
        if not (vals[0] < vals[1] and vals[2] < vals[3]):
            raise PlanningError(f"table bounds must have min < max, got {vals}")

    def contains(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        return ((xy[..., 0] >= self.x_min) & (xy[..., 0] <= self.x_max)
                & (xy[..., 1] >= self.y_min) & (xy[..., 1] <= self.y_max))


@dataclass(frozen=True)
class PlannerConfig:
    """Planner parameters (docs/planning.md lists them with their measured effect)."""

    max_speed: float = 1.5  # m/s, fastest initial COM speed a push may give
    min_speed: float = 0.05  # m/s, slowest push considered
    max_topple_probability: float = 0.35  # candidates predicted to topple more likely than this are rejected
    time_budget: float = 0.5  # s, wall time of one plan() call (at least one batch always runs)
    samples: int = 128  # candidates per CEM iteration
    elite_fraction: float = 0.1  # share of candidates that shape the next iteration (at least 4)
    max_iterations: int = 8  # CEM iterations at most (fewer when the budget runs out)
    horizon: int = 0  # steps rolled out; 0 = long enough to stop: (max_speed / (min_friction g) + settle) / dt
    settle_time: float = 0.6  # s added to the stopping time for the automatic horizon (wobble, spin)
    friction: float = 0.5  # nominal Coulomb friction: the initial speed guess sqrt(2 mu g d)
    min_friction: float = 0.35  # lowest friction expected: the reach bound v^2 / (2 mu g)
    max_offset_fraction: float = 0.85  # how far off the COM the line of push may pass, share of the lever limit
    min_contact_height: float = 0.005  # m above the table: lowest point the pusher can touch
    max_contact_height: float = 0.5  # m above the table: highest point the pusher can touch
    robust_candidates: int = 6  # distinct elites re-checked under perturbations (0 = no robustness check)
    robust_samples: int = 6  # perturbed roll-outs per re-checked elite
    robust_share: float = 0.25  # share of the time budget kept for the robustness check
    tip_check: bool = True  # also count the rigid-body tipping estimate (PushBody.tip_ratios) as topple risk
    pessimistic: bool = False  # hold the highest topple risk of the perturbed pushes to the limit, not the mean
    physics_check: bool = True  # finalists must also stay upright re-simulated on the cloud's hull (physics_check)
    friction_error: float = 0.2  # the physics check simulates the nominal friction and friction * (1 + this)
    physics_share: float = 0.15  # share of the time budget kept for the physics check
    max_spin: float = 40.0  # rad/s, pushes giving a faster initial angular velocity are infeasible (the model was
    #                         trained up to 40 rad/s: sim.push.PushConfig.max_spin)
    table: Optional[TableBounds] = field(default_factory=TableBounds)  # None: no table edge
    density: float = DEFAULT_DENSITY  # kg/m^3 for the mass estimate when no mass is given
    seed: int = 0  # candidate sampling is deterministic for a given seed
    detect_symmetry: bool = True  # a goal of unknown yaw_symmetry takes the cloud's (planning.symmetry)
    whole_cloud: bool = True  # clouds sample every side of the object: the physics check weighs the solid they
    #                           enclose, not their hull (shapes.solid); False for one camera's view
    physics_fusion: bool = True  # with whole clouds and a model whose checkpoint has topple fusion weights
    #                              (physdyn_ros.topple_fusion): the physics check's verdict is the fused probability

    def __post_init__(self) -> None:
        for name in ("max_speed", "min_speed", "time_budget", "settle_time", "friction", "min_friction",
                     "density", "max_spin"):
            v = finite(getattr(self, name), name)
            if v <= 0:
                raise PlanningError(f"{name} must be positive, got {v}")
        if self.min_speed >= self.max_speed:
            raise PlanningError(f"min_speed {self.min_speed} must be below max_speed {self.max_speed}")
        if not 0 <= finite(self.max_topple_probability, "max_topple_probability") <= 1:
            raise PlanningError(f"max_topple_probability must be in [0, 1], got {self.max_topple_probability}")
        if not 0 < finite(self.max_offset_fraction, "max_offset_fraction") <= 1:
            raise PlanningError(f"max_offset_fraction must be in (0, 1], got {self.max_offset_fraction}")
        if not 0 < finite(self.elite_fraction, "elite_fraction") <= 1:
            raise PlanningError(f"elite_fraction must be in (0, 1], got {self.elite_fraction}")
        lo, hi = finite(self.min_contact_height, "min_contact_height"), finite(self.max_contact_height,
                                                                                 "max_contact_height")
        if not 0 <= lo < hi:
            raise PlanningError(f"contact heights must satisfy 0 <= min_contact_height < max_contact_height, got "
                                f"{lo:g}, {hi:g}")
        if not 0 <= finite(self.robust_share, "robust_share") < 1:
            raise PlanningError(f"robust_share must be in [0, 1), got {self.robust_share}")
        if not 0 <= finite(self.physics_share, "physics_share") < 1 - self.robust_share:
            raise PlanningError(f"physics_share must be in [0, 1 - robust_share), got {self.physics_share}")
        if not 0 <= finite(self.friction_error, "friction_error") < 1:
            raise PlanningError(f"friction_error must be in [0, 1), got {self.friction_error}")
        optional = ("horizon", "robust_candidates", "robust_samples")
        for name in ("samples", "max_iterations") + optional:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (0 if name in optional else 1):
                kind = 'non-negative' if name in optional else 'positive'
                raise PlanningError(f"{name} must be a {kind} integer, got {v!r}")
        if self.samples < 8:
            raise PlanningError(f"samples must be >= 8, got {self.samples}")

    def reach(self) -> float:
        """Farthest a push of max_speed can slide at the lowest expected friction (m)."""
        return self.max_speed ** 2 / (2.0 * self.min_friction * GRAVITY)

    def auto_horizon(self, dt: float, max_horizon: int) -> int:
        if self.horizon:
            return int(min(self.horizon, max_horizon))
        t = self.max_speed / (self.min_friction * GRAVITY) + self.settle_time
        return int(min(max(math.ceil(t / dt), 5), max_horizon))


@dataclass(frozen=True)
class PushPlan:
    """The chosen push and what the model predicts it does."""

    lin_vel: np.ndarray  # (3,) m/s, COM velocity right after the push (world frame)
    ang_vel: np.ndarray  # (3,) rad/s, angular velocity right after the push (world frame)
    impulse: np.ndarray  # (3,) N s, = mass * lin_vel, horizontal
    contact_point: np.ndarray  # (3,) m, table frame: a point of the observed surface where the impulse is applied
    mass: float  # kg, the mass used for the impulse (given, or the hull / box estimate)
    offset: float  # m, signed distance of the line of push from the COM (+: left of the push direction)
    contact_height: float  # m above the table (= contact_point z)
    start: Pose2D
    goal: Goal
    final_pose: Pose2D  # predicted rest pose
    final_position: np.ndarray  # (3,) predicted final COM
    position_error: float  # m, predicted final distance to the goal
    yaw_error: float  # rad, predicted |final yaw - goal yaw| (0 when the goal ignores yaw)
    topple_probability: float  # predicted probability of toppling during the push
    robust_topple_probability: float  # mean topple probability over this push and its perturbations (robustness)
    worst_topple_probability: float  # highest topple probability over this push and its perturbations
    spread: float  # m, RMS distance of the perturbed pushes' rest positions from this push's (0: not checked)
    # the physics check's topple probability: the share of its hull runs that toppled, or with the topple fusion
    # the fused probability of the model and the solid's runs (-1: not checked)
    physics_topple_probability: float
    within_tolerance: bool  # the predicted final pose is within both tolerances
    # an estimate of the chance that the object rests within both tolerances and upright: the spread's
    # conservative estimate of ending within them (SpreadCalibration.within_level) times 1 - the plan's highest
    # topple risk; 1 when no push is needed, NaN for a model without a spread calibration
    success_probability: float
    trajectory: Trajectory  # predicted roll-out of the chosen push (frame 0 = start)
    planning_time: float  # s, wall time of the plan() call
    iterations: int  # CEM iterations run
    rollouts: int  # candidates rolled out in all
    horizon: int  # steps per roll-out
    body_source: str  # "hull" (from points) or "box" (shape code only): where contact point and mass came from
    model_id: str
    message: str

    @property
    def speed(self) -> float:
        return float(np.linalg.norm(self.lin_vel[:2]))
