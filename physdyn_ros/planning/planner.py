"""Single-push planning: which initial velocity (and impulse, contact point) brings an object to a goal pose.

    planner = PushPlanner(Predictor.load())                       # or any planning.models.DynamicsModel
    plan = planner.plan(cloud, Pose2D(0, 0, 0), Goal(Pose2D(0.15, 0.05, 0.3)))
    plan.lin_vel, plan.ang_vel, plan.impulse, plan.contact_point, plan.final_pose, plan.topple_probability

Search: the cross-entropy method (CEM) over four numbers per candidate push, (vx, vy, f, h): the horizontal
velocity of the COM, where the line of push passes the COM (a fraction f in [-1, 1] of the object's extent across
the push at that height) and the contact height h (a fraction of the heights the pusher can reach on this object,
config min/max_contact_height). The contact point is the first observed surface point on that line (planning.body),
and the angular velocity follows from the impulse there: every candidate is a push a single contact can make; a low
contact tips the object back against its topple. Each iteration rolls all candidates out with one `rollout_batch`
call and keeps the elite fraction; the first iteration puts up to 16 candidates (at most half) at the Coulomb-
sliding solution (`_Search.analytic_seeds`: the speed sqrt(2 mu g d) toward the goal and, per contact height, the
offset whose spin turns the object to the goal's yaw under sliding; each seed and three jittered copies), the rest
around the straight-line guess, gentle and low pushes included; later ones sample a Gaussian fitted to the elites.
Iterations stop when the time budget would be exceeded by the next one (cost per rolled-out step is measured on the
fly). The learned model rolls out only the search horizon (`head_timing=False`: its topple probability over those
steps is the whole push's), not the 60 steps a timed prediction needs: 3-4x the candidates per budget
(bench_planning's first pushes: 350-480 roll-outs in 0.2 s against 90-170).

Robustness: the best `robust_candidates` distinct elites are rolled out again under `robust_samples` small
perturbations each (speed, direction, offset, height: what a robot's execution and the perception get wrong).
The push whose perturbed outcomes cost least on average, and whose topple probability under that noise (the
mean over the push and its perturbations) stays under the limit, wins; its spread (RMS distance of the
perturbed rest positions from the nominal one) and that probability are reported. When none of them is safe
under that noise (a search that converged at the edge of the topple limit), the best pushes of the whole search
whose own risk lies under half the limit are checked the same way before the plan is refused. (Requiring every perturbed
push to stay under the limit refused 10 of 42 bench trials against 3, with as many topples: 52 % against 62 %
within three pushes, bench_planning.py --iterations 3.)

Cost of a candidate (lower is better), from its predicted final state:
    (position error / position tolerance)^2 + (yaw error / yaw tolerance)^2 (yaw ignored if tolerance >= pi)
    + (final speed / 0.1 m/s)^2, that speed taken from the last step's displacement (a trajectory still moving
      at the horizon has not reached its final pose)
    + 2 * topple probability + 1000 if the topple probability exceeds the limit or the COM leaves the table.

When no safe push reaches the goal, the safe push that gets closest wins (the closed loop pushes again).

Refusals (PlanningError, a ValueError, with the reason): non-finite or malformed poses and tolerances,
start or goal off the table, no shape, no contact height within reach, a goal farther than a push of at most
max_speed can slide (v^2 / (2 mu_min g)), and objects for which every push considered topples.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Optional, Union

import numpy as np

from ..conventions import GRAVITY
from ..learn.baselines import horizontal_radius
from ..learn.prior import MIN_RADIUS
from ..predictor import Predictor, ShapeCode, Trajectory, TrajectoryBatch
from ..shapes.core import DEFAULT_DENSITY
from .body import BodyError, PushBody, body_from_box, body_from_cloud
from .models import DynamicsModel

__all__ = ["Goal", "PlannerConfig", "PlanningError", "Pose2D", "PushPlan", "PushPlanner", "TableBounds",
           "wrap_angle", "yaw_of"]

#: Penalty added to candidates that break a hard limit (topple probability, table edge).
INFEASIBLE = 1000.0
#: Final speed (m/s) that costs as much as one tolerance of position error.
MOVING_SCALE = 0.1


class PlanningError(ValueError):
    """The request cannot be planned; the message says why (bad input, unreachable goal, every push topples)."""


#: Tipping energy ratio at which tip_probability is 1 - 1/e: a 4 x 4 x 16 cm box in pybullet stayed up at ratios
#: up to 0.33 and toppled from 0.5 (test_planning.py::test_tip_estimate_agrees_with_pybullet).
TIP_SCALE = 0.6


def tip_probability(ratio: np.ndarray) -> np.ndarray:
    """Topple risk from PushBody.tip_ratios: 1 - exp(-(r / TIP_SCALE)^2) (0.26 at r = 0.33, 0.50 at r = 0.5)."""
    return 1.0 - np.exp(-(np.asarray(ratio) / TIP_SCALE) ** 2)


def final_speed(positions: np.ndarray, dt: float) -> np.ndarray:
    """Horizontal speed (B,) over the last step of trajectories (B, T, 3), from the displacement.

    Not the fed-back velocity: the learned model's velocity channel can keep an offset after its predicted pose
    has stopped (bench/speed_bins.py: median 0.21 m/s on 0.4-0.8 m/s pushes whose positions were at rest), which
    made every short corrective push look unfinished to the planner.
    """
    return np.linalg.norm(positions[:, -1, :2] - positions[:, -2, :2], axis=-1) / dt


def wrap_angle(a: Union[float, np.ndarray]) -> Union[float, np.ndarray]:
    """Angle(s) wrapped into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi if isinstance(a, np.ndarray) else \
        (float(a) + math.pi) % (2 * math.pi) - math.pi


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Yaw (rad) of the x axis projected on the table, for (..., 4) quaternions (x, y, z, w)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _finite(value: Any, name: str) -> float:
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
            object.__setattr__(self, name, _finite(getattr(self, name), f"pose {name}"))

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
    """Where the object should come to rest. yaw_tolerance >= pi means any yaw is fine."""

    pose: Pose2D
    position_tolerance: float = 0.02  # m
    yaw_tolerance: float = math.radians(10.0)  # rad

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", Pose2D.of(self.pose, "goal pose"))
        for name in ("position_tolerance", "yaw_tolerance"):
            v = _finite(getattr(self, name), name)
            if v <= 0:
                raise PlanningError(f"{name} must be positive, got {v}")
            object.__setattr__(self, name, v)

    @property
    def ignores_yaw(self) -> bool:
        return self.yaw_tolerance >= math.pi


@dataclass(frozen=True)
class TableBounds:
    """Axis-aligned table top (m, table frame); the COM must stay inside."""

    x_min: float = -1.0
    x_max: float = 1.0
    y_min: float = -1.0
    y_max: float = 1.0

    def __post_init__(self) -> None:
        vals = [_finite(getattr(self, k), f"table {k}") for k in ("x_min", "x_max", "y_min", "y_max")]
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
    max_spin: float = 40.0  # rad/s, pushes giving a faster initial angular velocity are infeasible (the model was
    #                         trained up to 40 rad/s: sim.push.PushConfig.max_spin)
    table: Optional[TableBounds] = field(default_factory=TableBounds)  # None: no table edge
    density: float = DEFAULT_DENSITY  # kg/m^3 for the mass estimate when no mass is given
    seed: int = 0  # candidate sampling is deterministic for a given seed

    def __post_init__(self) -> None:
        for name in ("max_speed", "min_speed", "time_budget", "settle_time", "friction", "min_friction",
                     "density", "max_spin"):
            v = _finite(getattr(self, name), name)
            if v <= 0:
                raise PlanningError(f"{name} must be positive, got {v}")
        if self.min_speed >= self.max_speed:
            raise PlanningError(f"min_speed {self.min_speed} must be below max_speed {self.max_speed}")
        if not 0 <= _finite(self.max_topple_probability, "max_topple_probability") <= 1:
            raise PlanningError(f"max_topple_probability must be in [0, 1], got {self.max_topple_probability}")
        if not 0 < _finite(self.max_offset_fraction, "max_offset_fraction") <= 1:
            raise PlanningError(f"max_offset_fraction must be in (0, 1], got {self.max_offset_fraction}")
        if not 0 < _finite(self.elite_fraction, "elite_fraction") <= 1:
            raise PlanningError(f"elite_fraction must be in (0, 1], got {self.elite_fraction}")
        lo, hi = _finite(self.min_contact_height, "min_contact_height"), _finite(self.max_contact_height,
                                                                                 "max_contact_height")
        if not 0 <= lo < hi:
            raise PlanningError(f"contact heights must satisfy 0 <= min_contact_height < max_contact_height, got "
                                f"{lo:g}, {hi:g}")
        if not 0 <= _finite(self.robust_share, "robust_share") < 1:
            raise PlanningError(f"robust_share must be in [0, 1), got {self.robust_share}")
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
    spread: float  # m, RMS distance of the perturbed pushes' rest positions from this push's (0: not checked)
    within_tolerance: bool  # the predicted final pose is within both tolerances
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


# -------------------------------------------------------------------------------------------------- planner
class PushPlanner:
    """Plans single pushes with a dynamics model (a Predictor or any planning.models.DynamicsModel).

    Not thread-safe (the model is not): use one planner per thread, or serialise calls.
    """

    def __init__(self, model: DynamicsModel, config: PlannerConfig = PlannerConfig()) -> None:
        self.model = model
        self.config = config
        self._sec_per_step: Optional[float] = None  # measured cost of one candidate-step, seconds

    def warm_up(self) -> None:
        """Pay one-off costs (open3d's import for hulls, model warm-up, timing calibration) outside a request."""
        rng = np.random.default_rng(0)
        cloud = rng.uniform(-1.0, 1.0, size=(256, 3)) * np.array([0.05, 0.04, 0.03]) + np.array([0.0, 0.0, 0.03])
        self.plan(cloud, Pose2D(0.0, 0.0, 0.0), Goal(Pose2D(0.08, 0.0, 0.0), 0.05, math.pi),
                  config=replace(self.config, time_budget=0.3, max_iterations=2, table=None,
                                 max_topple_probability=1.0))

    # ------------------------------------------------------------------------------------------ inputs
    def _shape(self, shape: Any, cloud: Any) -> tuple[Any, Optional[np.ndarray]]:
        """(model code, cloud or None)."""
        if shape is None:
            raise PlanningError("no shape: give the object's cloud (N, 3) or its shape code")
        if isinstance(shape, ShapeCode) or (not isinstance(shape, (np.ndarray, list, tuple))
                                            and hasattr(shape, "centroid")):
            code = shape
        else:
            cloud = shape
            try:
                code = self.model.encode(cloud)
            except ValueError as exc:
                raise PlanningError(f"bad cloud: {exc}") from None
        if cloud is not None:
            cloud = np.asarray(cloud, dtype=np.float64)
            if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) < 4 or not np.all(np.isfinite(cloud)):
                raise PlanningError(f"cloud must be (N >= 4, 3) finite points, got shape {cloud.shape}")
        return code, cloud

    def _body(self, code: Any, cloud: Optional[np.ndarray], start: Pose2D, mass: Optional[float],
              cfg: PlannerConfig) -> PushBody:
        if mass is not None:
            m = _finite(mass, "mass")
            if m <= 0:
                raise PlanningError(f"mass must be positive, got {m}")
        try:
            if cloud is not None:
                body = body_from_cloud(cloud, cfg.density, mass)
            else:
                half = getattr(code, "half_extents", None)
                if half is None:
                    raise PlanningError("a shape code without half_extents needs the cloud for the contact point")
                body = body_from_box(np.asarray(code.centroid), half, float(getattr(code, "heading", 0.0)),
                                     cfg.density, mass)
        except BodyError as exc:
            raise PlanningError(str(exc)) from None
        # The geometry must be the object as seen at the start pose: a cloud from elsewhere gives wrong levers.
        gap = float(np.linalg.norm(body.com[:2] - start.xy))
        if gap > max(2.0 * body.radius(), 0.05):
            raise PlanningError(f"the object's points are centred {gap:.3f} m from the start pose; give the cloud "
                                "as observed at the start pose, in the table frame")
        return body

    # --------------------------------------------------------------------------------------------- plan
    def plan(self, shape: Any, start: Union[Pose2D, Any], goal: Union[Goal, Pose2D, Any], cloud: Any = None,
             mass: Optional[float] = None, config: Optional[PlannerConfig] = None) -> PushPlan:
        """Best single push from `start` to `goal` for the object `shape` (a cloud (N, 3) in the table frame,
        as observed at `start`, or a shape code of the model; with a code, `cloud` optionally gives the
        points for the contact geometry). `mass` (kg) scales the impulse; default: hull volume * density.
        Raises PlanningError with the reason when no push can be planned."""
        t0 = time.perf_counter()
        cfg = config or self.config
        start = Pose2D.of(start, "start pose")
        if not isinstance(goal, Goal):
            goal = Goal(Pose2D.of(goal, "goal pose"))
        if cfg.table is not None:
            for name, pose in (("start", start), ("goal", goal.pose)):
                if not cfg.table.contains(pose.xy):
                    t = cfg.table
                    raise PlanningError(f"{name} ({pose.x:.3f}, {pose.y:.3f}) is off the table "
                                        f"[{t.x_min:g}, {t.x_max:g}] x [{t.y_min:g}, {t.y_max:g}] m")
        code, cloud = self._shape(shape, cloud)
        body = self._body(code, cloud, start, mass, cfg)
        horizon = cfg.auto_horizon(float(self.model.dt), int(self.model.max_horizon))
        delta = goal.pose.xy - start.xy
        dist = float(np.linalg.norm(delta))
        yaw_gap = abs(float(wrap_angle(goal.pose.yaw - start.yaw)))
        if dist <= goal.position_tolerance and (goal.ignores_yaw or yaw_gap <= goal.yaw_tolerance):
            return self._no_push(start, goal, body, code, horizon, t0)
        if dist - goal.position_tolerance > cfg.reach():
            raise PlanningError(f"goal unreachable: it is {dist:.3f} m away, but a push of at most "
                                f"{cfg.max_speed:g} m/s slides at most {cfg.reach():.3f} m at friction "
                                f">= {cfg.min_friction:g} (v^2 / (2 mu g)); raise max_speed or push twice")
        search = _Search(self, code, body, start, goal, cfg, horizon, t0)
        best = search.run()
        return self._result(search, best, t0)

    def _no_push(self, start: Pose2D, goal: Goal, body: PushBody, code: Any, horizon: int, t0: float) -> PushPlan:
        z = float(np.asarray(code.centroid)[2])
        pos = np.tile([start.x, start.y, z], (horizon + 1, 1))
        q = np.tile([0.0, 0.0, 0.0, 1.0], (horizon + 1, 1))
        zeros = np.zeros((horizon + 1, 3))
        traj = Trajectory(float(self.model.dt), pos, q, zeros, zeros.copy(), np.zeros(horizon + 1))
        return PushPlan(lin_vel=np.zeros(3), ang_vel=np.zeros(3), impulse=np.zeros(3), contact_point=body.com.copy(),
                        mass=body.mass, offset=0.0, contact_height=float(body.com[2]), start=start, goal=goal,
                        final_pose=start, final_position=pos[-1],
                        position_error=float(np.linalg.norm(goal.pose.xy - start.xy)),
                        yaw_error=0.0 if goal.ignores_yaw else abs(float(wrap_angle(goal.pose.yaw - start.yaw))),
                        topple_probability=0.0, robust_topple_probability=0.0, spread=0.0, within_tolerance=True,
                        trajectory=traj, planning_time=time.perf_counter() - t0, iterations=0, rollouts=0,
                        horizon=horizon, body_source=body.source, model_id=str(self.model.model_id),
                        message="already within tolerance: no push needed")

    def _result(self, search: "_Search", best: "_Candidate", t0: float) -> PushPlan:
        cfg, goal, start = search.cfg, search.goal, search.start
        if best.off_table:
            raise PlanningError("every push considered leaves the table")
        worst = max(best.topple, best.robust_topple)
        if worst > cfg.max_topple_probability:
            raise PlanningError(f"no safe push: every push considered is predicted to topple the object (lowest "
                                f"topple probability {worst:.2f} > max_topple_probability "
                                f"{cfg.max_topple_probability:g}, contact heights {search.h_lo:.3f}-"
                                f"{search.h_hi:.3f} m); try a lower max_speed or a nearer goal")
        spin = float(np.linalg.norm(best.ang_vel))
        if spin > cfg.max_spin or not math.isfinite(best.cost) or best.cost >= INFEASIBLE:
            raise PlanningError(f"no feasible push: the best push considered spins the object at {spin:.1f} rad/s "
                                f"(max_spin {cfg.max_spin:g}) or breaks another limit; try a nearer goal")
        traj = best.trajectory
        final = traj.positions[-1]
        final_yaw = float(wrap_angle(start.yaw + float(yaw_of(traj.orientations[-1]))))
        within = best.pos_err <= goal.position_tolerance and (goal.ignores_yaw or best.yaw_err <= goal.yaw_tolerance)
        body = search.body
        lin = np.array([best.speed * best.direction[0], best.speed * best.direction[1], 0.0])
        yaw_text = "" if goal.ignores_yaw else f", yaw {math.degrees(best.yaw_err):.1f} deg"
        robust = f", spread {100 * best.spread:.1f} cm" if search.checked else ""
        msg = (f"{'within' if within else 'OUTSIDE'} tolerance: predicted to stop {100 * best.pos_err:.1f} cm"
               f"{yaw_text} from the goal (topple probability {worst:.2f}{robust}); push at "
               f"{100 * best.contact[2]:.1f} cm height; {search.iterations} CEM iterations, {search.rollouts} "
               f"roll-outs in {1e3 * (time.perf_counter() - t0):.0f} ms")
        return PushPlan(lin_vel=lin, ang_vel=best.ang_vel.copy(), impulse=body.mass * lin,
                        contact_point=best.contact.copy(), mass=body.mass, offset=float(best.offset),
                        contact_height=float(best.contact[2]), start=start, goal=goal,
                        final_pose=Pose2D(float(final[0]), float(final[1]), final_yaw), final_position=final.copy(),
                        position_error=float(best.pos_err), yaw_error=0.0 if goal.ignores_yaw else float(best.yaw_err),
                        topple_probability=float(best.topple), robust_topple_probability=float(best.robust_topple),
                        spread=float(best.spread), within_tolerance=bool(within), trajectory=traj,
                        planning_time=time.perf_counter() - t0, iterations=search.iterations,
                        rollouts=search.rollouts, horizon=search.horizon, body_source=body.source,
                        model_id=str(self.model.model_id), message=msg)


# ------------------------------------------------------------------------------------------------ the search
@dataclass
class _Candidate:
    cost: float
    direction: np.ndarray  # (2,)
    speed: float
    fraction: float
    height_fraction: float
    offset: float
    contact: np.ndarray  # (3,) table frame
    ang_vel: np.ndarray
    pos_err: float
    yaw_err: float
    topple: float
    off_table: bool
    trajectory: Trajectory
    robust_cost: float = math.inf  # mean cost over the perturbed pushes (robustness check)
    robust_topple: float = 0.0  # mean topple probability over the push and its perturbed pushes
    spread: float = 0.0  # m, RMS distance of the perturbed rest positions from this push's

    @property
    def params(self) -> np.ndarray:
        return np.array([self.speed * self.direction[0], self.speed * self.direction[1], self.fraction,
                         self.height_fraction])


#: Perturbations of the robustness check (standard deviations): relative speed, direction (rad), offset
#: fraction, height (m).
PERTURB_SPEED, PERTURB_ANGLE, PERTURB_FRACTION, PERTURB_HEIGHT = 0.08, math.radians(4.0), 0.08, 0.01


class _Search:
    """One CEM run (state shared by the iterations and the robustness check)."""

    def __init__(self, planner: PushPlanner, code: Any, body: PushBody, start: Pose2D, goal: Goal,
                 cfg: PlannerConfig, horizon: int, t0: float) -> None:
        self.planner, self.model, self.code, self.body = planner, planner.model, code, body
        self.start, self.goal, self.cfg, self.horizon, self.t0 = start, goal, cfg, horizon, t0
        self.deadline = t0 + cfg.time_budget
        robust = cfg.robust_candidates > 0 and cfg.robust_samples > 0
        self.cem_deadline = t0 + cfg.time_budget * ((1.0 - cfg.robust_share) if robust else 1.0)
        self.rng = np.random.default_rng(cfg.seed)
        self.iterations = 0
        self.rollouts = 0
        self.checked = False
        self.seen: list[_Candidate] = []  # every candidate of the CEM iterations
        # the learned model's topple probability over the search horizon is the whole push's (not the prefix of a
        # 60-step run: the outcome matters, and 16 steps cost 16)
        self.extra = {"head_timing": False} if isinstance(self.model, Predictor) else {}
        self.z0 = float(np.asarray(code.centroid)[2])
        try:
            self.h_lo, self.h_hi = body.height_range(cfg.min_contact_height, cfg.max_contact_height)
        except BodyError as exc:
            raise PlanningError(str(exc)) from None
        delta = goal.pose.xy - start.xy
        self.dist = float(np.linalg.norm(delta))
        self.heading = math.atan2(delta[1], delta[0]) if self.dist > 1e-9 else start.yaw
        # Coulomb guess for the speed; spin and toppling change it, CEM finds the rest
        self.speed0 = float(np.clip(math.sqrt(2 * cfg.friction * GRAVITY * max(self.dist, 1e-3)),
                                    cfg.min_speed, cfg.max_speed))

    # -- candidates --------------------------------------------------------------------------------------
    def _first(self, n: int) -> np.ndarray:
        """(n, 4) params (vx, vy, f, h): up to four per seed (at most half of n) at the Coulomb-sliding solution
        (analytic_seeds: the speed and the offset that slide to the goal and turn to its yaw, at several heights;
        each seed and three jittered copies), the rest a broad spread around the straight-line push, gentle and
        low pushes included (they are the ones that do not topple tall objects)."""
        seeds = self.analytic_seeds()
        n_seed = min(n // 2, 4 * len(seeds))
        n_wide = n - n_seed
        ang = self.heading + self.rng.uniform(-0.7, 0.7, n_wide)
        speed = self.speed0 * np.exp(self.rng.uniform(np.log(0.3), np.log(2.0), n_wide))
        f = self.rng.uniform(-self.cfg.max_offset_fraction, self.cfg.max_offset_fraction, n_wide)
        h = np.where(np.arange(n_wide) % 2 == 0, self.rng.uniform(0.0, 0.3, n_wide), self.rng.uniform(0.0, 1.0, n_wide))
        wide = np.stack([speed * np.cos(ang), speed * np.sin(ang), f, h], axis=1)
        wide[0] = [self.speed0 * math.cos(self.heading), self.speed0 * math.sin(self.heading), 0.0, 0.0]
        if n_seed == 0:
            return wide
        near = seeds[np.arange(n_seed) % len(seeds)].copy()
        exact = min(len(seeds), n_seed)
        near[exact:] += self.rng.normal(0.0, 1.0, (n_seed - exact, 4)) * np.array(
            [0.05 * self.speed0, 0.05 * self.speed0, 0.05, 0.05])  # the seeds themselves, then jittered copies
        return np.concatenate([near, wide])

    def analytic_seeds(self, heights: int = 4, offsets: int = 33) -> np.ndarray:
        """(K, 4) pushes that reach the goal under Coulomb sliding (learn/prior.py's model: constant deceleration
        mu g of the speed, mu g / r of the spin, r the cloud's RMS horizontal radius): speed sqrt(2 mu g d) toward
        the goal and, at each of `heights` contact heights, the line offset whose impulse spins the object at
        sqrt(2 (mu g / r) |turn|) toward the goal's yaw (the offsets tried: `offsets` across the object). With
        the yaw ignored, the centred push at each height. The learned model then corrects what sliding misses
        (spin-slide coupling, tilt); a CEM started only around the straight push needed 2 s instead of 0.2 s to
        find pushes within tolerance (bench/bench_planning.py trials)."""
        cfg = self.cfg
        speed = self.speed0
        d = np.array([math.cos(self.heading), math.sin(self.heading)])
        hf = (np.arange(heights) + 0.5) / heights
        if self.goal.ignores_yaw:
            return np.array([[speed * d[0], speed * d[1], 0.0, h] for h in hf])
        turn = float(wrap_angle(self.goal.pose.yaw - self.start.yaw))
        radius = max(float(horizontal_radius(self.body.points[None])[0]), MIN_RADIUS)  # the prior's spin lever
        want = math.copysign(math.sqrt(2.0 * cfg.friction * GRAVITY / radius * abs(turn)), turn)
        f = np.linspace(-cfg.max_offset_fraction, cfg.max_offset_fraction, offsets)
        ff, hh = np.meshgrid(f, hf)  # (H, F)
        dirs = np.tile(d, (ff.size, 1))
        contacts, _ = self.body.contacts(dirs, ff.ravel(), self.h_lo + hh.ravel() * (self.h_hi - self.h_lo))
        v = np.concatenate([speed * dirs, np.zeros((ff.size, 1))], axis=1)
        wz = self.body.angular_velocity(v, contacts)[:, 2].reshape(hh.shape)
        best = np.argmin(np.abs(wz - want), axis=1)  # per height
        return np.array([[speed * d[0], speed * d[1], f[j], h] for j, h in zip(best, hf)])

    def _project(self, params: np.ndarray) -> tuple[np.ndarray, ...]:
        """Clip to the feasible set: speed within limits, offset within the lever fraction, height reachable."""
        v = params[:, :2]
        s = np.linalg.norm(v, axis=1)
        d = np.where(s[:, None] > 1e-9, v / np.maximum(s, 1e-12)[:, None],
                     np.array([math.cos(self.heading), math.sin(self.heading)]))
        s = np.clip(s, self.cfg.min_speed, self.cfg.max_speed)
        f = np.clip(params[:, 2], -self.cfg.max_offset_fraction, self.cfg.max_offset_fraction)
        return d, s, f, np.clip(params[:, 3], 0.0, 1.0)

    def evaluate(self, params: np.ndarray, keep: bool = True) -> list[_Candidate]:
        """Roll out candidate pushes (n, 4); keep: remember them in self.seen (the robustness fallback's pool)."""
        d, s, f, hf = self._project(params)
        contacts, e = self.body.contacts(d, f, self.h_lo + hf * (self.h_hi - self.h_lo))
        v = np.concatenate([s[:, None] * d, np.zeros((len(s), 1))], axis=1)
        w = self.body.angular_velocity(v, contacts)
        p0 = np.array([self.start.x, self.start.y, self.z0])
        t = time.perf_counter()
        try:
            batch = self.model.rollout_batch(self.code, v, w, horizon=self.horizon, positions=p0, **self.extra)
        except ValueError as exc:  # e.g. a shape code from another model
            raise PlanningError(f"the dynamics model refused the request: {exc}") from None
        spent = time.perf_counter() - t
        per_step = spent / (len(s) * self.horizon)
        ema = self.planner._sec_per_step
        self.planner._sec_per_step = per_step if ema is None else 0.5 * ema + 0.5 * per_step
        self.rollouts += len(s)
        tip = self.body.tip_ratios(v, w, self.cfg.friction) if self.cfg.tip_check else None
        costs, pos_err, yaw_err, topple, off = self.costs(batch, tip)
        costs = costs + INFEASIBLE * (np.linalg.norm(w, axis=1) > self.cfg.max_spin)
        cands = [_Candidate(float(costs[i]), d[i], float(s[i]), float(f[i]), float(hf[i]), float(e[i]), contacts[i],
                            w[i], float(pos_err[i]), float(yaw_err[i]), float(topple[i]), bool(off[i]), batch[i])
                 for i in range(len(s))]
        if keep:
            self.seen.extend(cands)
        return cands

    def costs(self, batch: TrajectoryBatch, tip: Optional[np.ndarray] = None) -> tuple[np.ndarray, ...]:
        g, cfg = self.goal, self.cfg
        final = batch.positions[:, -1, :2]
        pos_err = np.linalg.norm(final - g.pose.xy, axis=1)
        yaw = self.start.yaw + yaw_of(batch.orientations[:, -1])
        yaw_err = np.abs(wrap_angle(yaw - g.pose.yaw))
        topple = batch.topple_prob.max(axis=1)
        if tip is not None:
            topple = np.maximum(topple, tip_probability(tip))
        speed_end = final_speed(batch.positions, float(self.model.dt))
        cost = (pos_err / g.position_tolerance) ** 2 + (speed_end / MOVING_SCALE) ** 2 + 2.0 * topple
        if not g.ignores_yaw:
            cost = cost + (yaw_err / g.yaw_tolerance) ** 2
        off: np.ndarray = np.zeros(len(cost), dtype=bool)
        if cfg.table is not None:
            off = np.logical_not(np.all(cfg.table.contains(batch.positions[..., :2]), axis=1))
        cost = cost + INFEASIBLE * ((topple > cfg.max_topple_probability) | off)
        cost = np.where(np.isfinite(cost), cost, np.inf)  # a diverging model must never win
        return cost, pos_err, yaw_err, topple, off

    def _batch_size(self, deadline: float) -> int:
        """Candidates that fit before `deadline` (a 32-candidate probe while the cost is unknown)."""
        n = self.cfg.samples
        per = self.planner._sec_per_step
        if per is None:
            return min(n, 32)
        left = deadline - time.perf_counter()
        fit = int(0.85 * left / max(per * self.horizon, 1e-9))
        return min(n, fit)

    # -- CEM -----------------------------------------------------------------------------------------------
    def run(self) -> _Candidate:
        cfg = self.cfg
        lo = np.array([-cfg.max_speed, -cfg.max_speed, -cfg.max_offset_fraction, 0.0])
        hi = np.array([cfg.max_speed, cfg.max_speed, cfg.max_offset_fraction, 1.0])
        std_floor = np.array([0.01, 0.01, 0.02, 0.02])
        best: Optional[_Candidate] = None
        elites: list[_Candidate] = []
        mean: Optional[np.ndarray] = None
        std: Optional[np.ndarray] = None
        while self.iterations < cfg.max_iterations:
            n = self._batch_size(self.cem_deadline)
            if self.iterations > 0 and n < 8:
                break  # the budget is spent
            n = max(n, 8)
            if mean is None or std is None:
                params = self._first(n)
            else:
                params = np.clip(mean + std * self.rng.standard_normal((n, 4)), lo, hi)
            cands = self.evaluate(params)
            self.iterations += 1
            # elitism: last iteration's elites compete again (roll-outs are deterministic: no re-evaluation)
            pool = sorted(cands + elites, key=lambda c: c.cost)
            k = max(4, int(round(cfg.elite_fraction * len(cands))))
            elites = pool[:k]
            if best is None or elites[0].cost < best.cost:
                best = elites[0]
            ep = np.array([c.params for c in elites])
            new_mean, new_std = ep.mean(axis=0), ep.std(axis=0) + std_floor
            mean = new_mean if mean is None else 0.9 * new_mean + 0.1 * mean
            std = new_std if std is None else 0.8 * new_std + 0.2 * std
            if best.cost < 0.05 and cfg.robust_candidates == 0:  # far inside the tolerances: more buys nothing
                break
        assert best is not None
        return self.robust(elites, best)

    def robust(self, elites: list[_Candidate], best: _Candidate) -> _Candidate:
        """Re-check the best distinct elites under perturbed execution; the most robust safe one wins. When none
        of them is safe under that noise (the search converged on risky pushes), the best pushes of the whole
        search whose own topple risk lies under half the limit are checked the same way."""
        cfg = self.cfg
        k, m = cfg.robust_candidates, cfg.robust_samples
        if k == 0 or m == 0:
            return best
        chosen = _distinct(elites, k)
        if not chosen:
            return best
        self._perturb(chosen, m)
        safe = [c for c in chosen if c.robust_topple <= cfg.max_topple_probability]
        if not safe:
            calm = sorted((c for c in self.seen if c.topple <= 0.5 * cfg.max_topple_probability), key=lambda c: c.cost)
            # within the budget if it allows (at least one candidate: a refusal must have looked)
            room = max(1, min(k, self._batch_size(self.deadline) // m))
            fallback = [c for c in _distinct(calm, k) if all(c is not o for o in chosen)][:room]
            if fallback:
                self._perturb(fallback, m)
                safe = [c for c in fallback if c.robust_topple <= cfg.max_topple_probability]
                chosen += fallback
        return min(safe or chosen, key=lambda c: c.robust_cost)

    def _perturb(self, chosen: list[_Candidate], m: int) -> None:
        """Roll each candidate out again under m perturbations (speed, direction, offset, height); fills its
        robust_cost, robust_topple and spread."""
        base = np.array([c.params for c in chosen])  # (K, 4)
        speed = np.hypot(base[:, 0], base[:, 1])[:, None] * np.exp(PERTURB_SPEED * self.rng.standard_normal((len(
            chosen), m)))
        ang = np.arctan2(base[:, 1], base[:, 0])[:, None] + PERTURB_ANGLE * self.rng.standard_normal((len(chosen), m))
        frac = base[:, 2:3] + PERTURB_FRACTION * self.rng.standard_normal((len(chosen), m))
        span = max(self.h_hi - self.h_lo, 1e-6)
        height = base[:, 3:4] + PERTURB_HEIGHT / span * self.rng.standard_normal((len(chosen), m))
        params = np.stack([speed * np.cos(ang), speed * np.sin(ang), frac, height], axis=-1).reshape(-1, 4)
        perturbed = self.evaluate(params, keep=False)
        self.checked = True
        for i, c in enumerate(chosen):
            group = perturbed[i * m:(i + 1) * m]
            c.robust_cost = float(np.mean([min(p.cost, INFEASIBLE) for p in group] + [c.cost]))
            # the push's topple probability under execution noise: the mean over it and its perturbations
            c.robust_topple = float(np.mean([c.topple] + [p.topple for p in group]))
            finals = np.array([p.trajectory.positions[-1, :2] for p in group])
            c.spread = float(np.sqrt(np.mean(np.sum((finals - c.trajectory.positions[-1, :2]) ** 2, axis=1))))


def _distinct(cands: list[_Candidate], k: int) -> list[_Candidate]:
    """The first k feasible candidates each a little different from those before it (cands sorted by cost)."""
    chosen: list[_Candidate] = []
    for c in cands:
        if c.cost >= INFEASIBLE:
            break
        if all(np.abs(c.params - o.params).max() > 1e-3 for o in chosen):
            chosen.append(c)
        if len(chosen) == k:
            break
    return chosen
