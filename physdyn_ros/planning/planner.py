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
"""Single-push planning: which initial velocity (and impulse, contact point) brings an object to a goal pose.

    planner = PushPlanner(Predictor.load())                       # or any planning.models.DynamicsModel
    plan = planner.plan(cloud, Pose2D(0, 0, 0), Goal(Pose2D(0.15, 0.05, 0.3)))
    plan.lin_vel, plan.ang_vel, plan.impulse, plan.contact_point, plan.final_pose, plan.topple_probability

The search itself (CEM over candidate pushes, the robustness check, the cost) is planning/search.py; the value
types (Pose2D, Goal, TableBounds, PlannerConfig, PushPlan) are planning/types.py.

Refusals (PlanningError, a ValueError, with the reason): non-finite or malformed poses and tolerances,
start or goal off the table, no shape, no contact height within reach, a goal farther than a push of at most
max_speed can slide (v^2 / (2 mu_min g)), and objects for which every push considered topples.

Yaw goals the object can show: a goal whose yaw_symmetry is not known takes the cloud's (planning.symmetry,
config.detect_symmetry): the yaw goal of an upright cylinder is ignored, a square box's taken modulo 90 deg,
and the plan's message says so.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Optional, Sequence, Union

import numpy as np

from ..predictor import Predictor, ShapeCode, Trajectory
from ..topple_fusion import FusionWeights, fusion_path
from .body import BodyError, PushBody, body_from_box, body_from_cloud
from .models import DynamicsModel
from .physics_check import PhysicsCheck
from .search import INFEASIBLE, Candidate, Search, StepCost
from .symmetry import symmetry_note, yaw_symmetry
from .types import (Goal, PlannerConfig, PlanningError, Pose2D, PushPlan, finite, fold_yaw, wrap_angle,
                    yaw_of)

__all__ = ["PushPlanner"]


class PushPlanner:
    """Plans single pushes with a dynamics model (a Predictor or any planning.models.DynamicsModel).

    Not thread-safe (the model is not): use one planner per thread, or serialise calls.
    """

    def __init__(self, model: DynamicsModel, config: PlannerConfig = PlannerConfig(),
                 ensemble: Sequence[DynamicsModel] = ()) -> None:
        """`ensemble`: further models of the same dynamics (members trained from other seeds and data, e.g.
        the checkpoints resources.ensemble_paths names, loaded): the search runs on `model`, the robustness check on
        every member too, each push's topple risk the highest of theirs and its spread widened by their
        disagreement. Members encode the object's points: a shape code without points is checked by `model`
        alone (the plan's message says so)."""
        for member in ensemble:
            if abs(float(member.dt) - float(model.dt)) > 1e-9:
                raise ValueError(f"ensemble member {member.model_id} steps {member.dt} s, the model {model.dt} s")
            if int(member.max_horizon) < int(model.max_horizon):
                raise ValueError(f"ensemble member {member.model_id} rolls out at most {member.max_horizon} steps, "
                                 f"fewer than the model's {model.max_horizon}")
        self.model = model
        self.ensemble = list(ensemble)
        self.config = config
        self._step_cost = StepCost()  # measured cost of one candidate-step, shared by this planner's searches
        self._physics: Optional[PhysicsCheck] = None  # created on the first plan that checks (imports pybullet)
        self._weights: tuple[Any, Optional[FusionWeights]] = (None, None)  # (file stamp, weights) read last

    def close(self) -> None:
        """Release the physics check's simulator (the model stays the caller's)."""
        if self._physics is not None:
            self._physics.close()
            self._physics = None

    def physics(self, cfg: PlannerConfig) -> Optional[PhysicsCheck]:
        """The physics check for `cfg` (None when it checks none), kept while its friction stays the same; with
        the model's topple fusion weights where cfg.physics_fusion asks for them and the checkpoint has them."""
        if not cfg.physics_check:
            return None
        frictions = (cfg.friction * (1.0 - cfg.friction_error), cfg.friction * (1.0 + cfg.friction_error))
        fusion = self.fusion_weights() if cfg.physics_fusion and cfg.whole_cloud else None
        if self._physics is None or self._physics.frictions != frictions or self._physics.fusion != fusion:
            self.close()
            self._physics = PhysicsCheck(cfg.friction, cfg.friction_error, fusion=fusion)
        return self._physics

    def fusion_weights(self) -> Optional[FusionWeights]:
        """The topple fusion weights stored beside the model's checkpoint for this model (None: there are none,
        or the model is not a loaded checkpoint); a file that cannot be read raises PlanningError."""
        path = getattr(self.model, "path", "")
        if not path or not fusion_path(path).is_file():
            return None
        st = fusion_path(path).stat()
        stamp = (str(path), st.st_mtime_ns, st.st_size)
        if self._weights[0] != stamp:  # read once per version of the file
            try:
                self._weights = (stamp, FusionWeights.load(fusion_path(path)))
            except (OSError, ValueError) as exc:
                raise PlanningError(str(exc)) from None
        weights = self._weights[1]
        return weights if weights is not None and weights.model_id == str(self.model.model_id) else None

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

    def _members(self, code: Any, cloud: Optional[np.ndarray]) -> tuple[list[tuple[DynamicsModel, Any]], str]:
        """(member, its code of the object) for each ensemble member, each encoding the points itself (the cloud,
        else the code's own points), and a note for the plan's message: a code without points cannot be re-encoded,
        the model then checks alone."""
        if not self.ensemble:
            return [], ""
        points = cloud if cloud is not None else getattr(code, "points", None)
        if points is None:
            return [], "checked by the model alone: the ensemble's members need the object's points, the code has none"
        try:
            return [(member, member.encode(points)) for member in self.ensemble], ""
        except ValueError as exc:
            raise PlanningError(f"bad cloud: {exc}") from None

    def _body(self, code: Any, cloud: Optional[np.ndarray], start: Pose2D, mass: Optional[float],
              cfg: PlannerConfig) -> PushBody:
        if mass is not None:
            m = finite(mass, "mass")
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
        if goal.yaw_symmetry is None and cfg.detect_symmetry and cloud is not None:
            goal = replace(goal, yaw_symmetry=yaw_symmetry(cloud))
        body = self._body(code, cloud, start, mass, cfg)
        horizon = cfg.auto_horizon(float(self.model.dt), int(self.model.max_horizon))
        delta = goal.pose.xy - start.xy
        dist = float(np.linalg.norm(delta))
        yaw_gap = fold_yaw(abs(float(wrap_angle(goal.pose.yaw - start.yaw))), goal.yaw_symmetry)
        if dist <= goal.position_tolerance and (goal.ignores_yaw or yaw_gap <= goal.yaw_tolerance):
            return self._no_push(start, goal, body, code, horizon, t0)
        if dist - goal.position_tolerance > cfg.reach():
            raise PlanningError(f"goal unreachable: it is {dist:.3f} m away, but a push of at most "
                                f"{cfg.max_speed:g} m/s slides at most {cfg.reach():.3f} m at friction "
                                f">= {cfg.min_friction:g} (v^2 / (2 mu g)); raise max_speed or push twice")
        others, note = self._members(code, cloud)
        search = Search(self.model, self._step_cost, code, body, start, goal, cfg, horizon, t0, self.physics(cfg),
                        others)
        best = search.run()
        plan = self._result(search, best, t0)
        return replace(plan, message=f"{plan.message}; {note}") if note else plan

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
                        yaw_error=0.0 if goal.ignores_yaw else float(fold_yaw(abs(float(wrap_angle(
                            goal.pose.yaw - start.yaw))), goal.yaw_symmetry)),
                        topple_probability=0.0, robust_topple_probability=0.0, worst_topple_probability=0.0,
                        spread=0.0, physics_topple_probability=-1.0, within_tolerance=True,
                        success_probability=1.0, trajectory=traj, planning_time=time.perf_counter() - t0,
                        iterations=0, rollouts=0,
                        horizon=horizon, body_source=body.source, model_id=str(self.model.model_id),
                        message=_with_note("already within tolerance: no push needed", goal))

    def _result(self, search: Search, best: Candidate, t0: float) -> PushPlan:
        cfg, goal, start = search.cfg, search.goal, search.start
        if best.off_table:
            raise PlanningError("every push considered leaves the table")
        worst = best.risk(cfg.pessimistic)
        if best.physics_topple > cfg.max_topple_probability and best.topple <= cfg.max_topple_probability \
                and search.fused:
            raise PlanningError(f"no safe push: the pushes the model finds safe topple the object re-simulated on "
                                f"the solid its cloud encloses (topple probability {best.physics_topple:.2f} of the "
                                f"safest, the model fused with runs at friction {cfg.friction:g} and less and "
                                "more); try a lower max_speed or a nearer goal")
        if best.physics_topple > cfg.max_topple_probability and best.topple <= cfg.max_topple_probability:
            raise PlanningError(f"no safe push: the pushes the model finds safe topple the object re-simulated on "
                                f"its hull (in {100 * best.physics_topple:.0f} % of the runs of the safest, friction "
                                f"{cfg.friction:g} and {100 * cfg.friction_error:.0f} % more); try a lower max_speed "
                                "or a nearer goal")
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
        success = math.nan
        if isinstance(self.model, Predictor):  # the chosen push's calibrated spread (~2 ms)
            again = self.model.rollout(replace(search.code, points=None), best.lin_vel, best.ang_vel, search.horizon,
                                       position=traj.positions[0], orientation=traj.orientations[0], spread=True)
            traj = replace(traj, spread=again.spread)
            cal = self.model.spread_calibration
            if cal is not None and again.spread is not None:
                # the radii are about `again`'s rest pose, the errors the search's: the margins give up their gap
                gap = float(np.linalg.norm(again.positions[-1, :2] - traj.positions[-1, :2]))
                turn = abs(float(wrap_angle(float(yaw_of(again.orientations[-1]) - yaw_of(traj.orientations[-1])))))
                yaw_margin = None if goal.ignores_yaw else goal.yaw_tolerance - best.yaw_err - turn
                level = cal.within_level(again.spread.sensitivity, goal.position_tolerance - best.pos_err - gap,
                                         yaw_margin)
                topple = max(worst, best.physics_topple, float(traj.topple_prob.max()))
                success = level * (1.0 - topple)
        final = traj.positions[-1]
        final_yaw = float(wrap_angle(start.yaw + float(yaw_of(traj.orientations[-1]))))
        within = best.pos_err <= goal.position_tolerance and (goal.ignores_yaw or best.yaw_err <= goal.yaw_tolerance)
        body = search.body
        lin = np.array([best.speed * best.direction[0], best.speed * best.direction[1], 0.0])
        yaw_text = "" if goal.ignores_yaw else f", yaw {math.degrees(best.yaw_err):.1f} deg"
        robust = f", spread {100 * best.spread:.1f} cm" if search.checked else ""
        if search.checked and search.others:
            robust += f" over {1 + len(search.others)} models"
        if best.physics_topple >= 0 and search.fused:
            robust += f", fused with the solid's physics {best.physics_topple:.2f}"
        elif best.physics_topple >= 0:
            robust += f", hull physics topples {100 * best.physics_topple:.0f} % of its runs"
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
                        worst_topple_probability=float(max(best.topple, best.worst_topple)),
                        spread=float(best.spread), physics_topple_probability=float(best.physics_topple),
                        within_tolerance=bool(within), success_probability=float(success), trajectory=traj,
                        planning_time=time.perf_counter() - t0, iterations=search.iterations,
                        rollouts=search.rollouts, horizon=search.horizon, body_source=body.source,
                        model_id=str(self.model.model_id), message=_with_note(msg, goal))


def _with_note(message: str, goal: Goal) -> str:
    """The message, with what the object's symmetry did to the yaw goal (a yaw the cloud cannot show)."""
    note = symmetry_note(goal.yaw_symmetry)
    return f"{message}; {note}" if note else message
