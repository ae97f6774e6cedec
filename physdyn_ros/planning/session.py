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
"""One push-to-goal episode: when to stop, why, and how the next push is aimed (no I/O, no planner calls).

Shared by the pybullet closed loop (planning.closed_loop) and the `push_to_goal` action (nodes.pusher_node), so a
simulated bench and a robot stop for the same reasons and adapt the same way:

    session = PushSession(goal, max_pushes=3)
    session.observe_shape(cloud)            # the yaw the object can show (planning.symmetry), once per episode
    while (stop := session.check(pose, toppled)) is None:
        plan = planner.plan(cloud, pose, session.aim(pose), ...)     # PlanningError -> session.refused(reason)
        ... execute, observe where the object came to rest ...
        session.record(plan_start, plan_final, observed, toppled)
    stop.outcome, stop.message

Adaptation between pushes (`adapt`): the learned model's slide distance can be off by a factor for one object
(friction, mass distribution it cannot see). After each push the ratio of the observed to the predicted
displacement is measured (pushes that moved at least MIN_ADAPT_DISTANCE); the next push aims at the goal
brought nearer (or farther) by their geometric mean, clipped to GAIN_RANGE, so a model that under-predicts the
slide by 30 % is asked for 1/1.3 of the distance. The turn is not corrected the same way (neither by the mean
observed minus predicted yaw change nor by its ratio): the model's yaw errors differ from push to push, so last
push's error says little about the next one's, and both corrections lowered the closed loop's success on
bench/bench_planning.py. This is the closed loop's "observe and adapt" step; the observed states of a push can
also be fed to the model while it moves (planning.adapt, `steps_in`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from .symmetry import yaw_symmetry
from .types import Goal, Pose2D, TableBounds

#: Outcomes of an episode: the goal reached, or why not. `refused`: the planner found no safe push (or the
#: request was invalid); `toppled`: the object fell over; `out_of_pushes`: max_pushes used without reaching the
#: goal; `cancelled`: the caller stopped it.
OUTCOMES = ("reached", "refused", "toppled", "out_of_pushes", "cancelled")
#: Observed / predicted slide ratios are clipped into this range (one bad observation must not send the next
#: push off the table).
GAIN_RANGE = (0.5, 2.0)
#: m: pushes predicted or observed to move less than this say nothing about the slide ratio.
MIN_ADAPT_DISTANCE = 0.01
#: A goal farther than one push reaches is split into equal legs of at most this fraction of the reach (the
#: planner then has speed to spare), each leg's end an intermediate goal ...
LEG_REACH = 0.8
#: ... reached within this fraction of the leg's length (or the goal's own tolerance, if larger), any yaw.
LEG_TOLERANCE = 0.25


@dataclass(frozen=True)
class Stop:
    """Why an episode ended."""

    outcome: str  # one of OUTCOMES
    message: str

    @property
    def success(self) -> bool:
        return self.outcome == "reached"


@dataclass(frozen=True)
class PushStep:
    """One executed push: where it started, where the model said it would stop, where it stopped."""

    start: Pose2D
    predicted: Pose2D
    observed: Pose2D
    toppled: bool
    position_error: float  # m, observed rest position to the goal
    yaw_error: float  # rad (0 when the goal ignores the yaw)


def goal_errors(pose: Pose2D, goal: Goal) -> tuple[float, float]:
    """(position error m, yaw error rad; 0 when the goal ignores the yaw) of a pose; the yaw error folded by the
    goal's yaw_symmetry, the planner's rule (Goal.yaw_error)."""
    pos_err = float(np.linalg.norm(pose.xy - goal.pose.xy))
    yaw_err = 0.0 if goal.ignores_yaw else float(goal.yaw_error(pose.yaw))
    return pos_err, yaw_err


@dataclass
class PushSession:
    goal: Goal
    max_pushes: int = 3
    adapt: bool = True  # aim the next push by the observed / predicted slide ratio
    steps: list[PushStep] = field(default_factory=list)

    def __post_init__(self) -> None:
        if isinstance(self.max_pushes, bool) or not isinstance(self.max_pushes, (int, np.integer)) \
                or self.max_pushes < 1:
            raise ValueError(f"max_pushes must be an integer >= 1, got {self.max_pushes!r}")

    # ------------------------------------------------------------------------------------------- shape
    def observe_shape(self, cloud: Optional[np.ndarray]) -> Optional[int]:
        """Take the yaw symmetry of the object from its cloud (table frame) when the goal does not give it
        (planning.symmetry.yaw_symmetry): from then on the episode's goal errors, stops and aims fold the yaw
        the way the planner does. Returns the goal's yaw_symmetry (None: no cloud, still unknown)."""
        if self.goal.yaw_symmetry is None and cloud is not None:
            self.goal = replace(self.goal, yaw_symmetry=yaw_symmetry(cloud))
        return self.goal.yaw_symmetry

    # ------------------------------------------------------------------------------------------- queries
    def within(self, pose: Pose2D) -> bool:
        pos_err, yaw_err = goal_errors(pose, self.goal)
        return pos_err <= self.goal.position_tolerance and (self.goal.ignores_yaw or yaw_err <= self.goal.yaw_tolerance)

    def check(self, pose: Pose2D, toppled: bool) -> Optional[Stop]:
        """The reason to stop now, with the object at `pose`, or None when another push should be planned."""
        pos_err, yaw_err = goal_errors(pose, self.goal)
        where = f"{100 * pos_err:.1f} cm" + ("" if self.goal.ignores_yaw else f", {math.degrees(yaw_err):.1f} deg")
        n = len(self.steps)
        if toppled:
            return Stop("toppled", f"the object toppled during push {n}" if n else "the object lies toppled")
        if self.within(pose):
            return Stop("reached", f"within tolerance after {n} push(es): {where} from the goal")
        if n >= self.max_pushes:
            return Stop("out_of_pushes", f"still {where} from the goal after {n} push(es) (max_pushes "
                                         f"{self.max_pushes})")
        return None

    def refused(self, reason: str) -> Stop:
        return Stop("refused", f"push {len(self.steps) + 1}: {reason}")

    @property
    def gain(self) -> float:
        """Observed / predicted slide distance, geometric mean over the pushes so far (1 with none)."""
        ratios = []
        for s in self.steps:
            pred = float(np.linalg.norm(s.predicted.xy - s.start.xy))
            obs = float(np.linalg.norm(s.observed.xy - s.start.xy))
            if not s.toppled and max(pred, obs) >= MIN_ADAPT_DISTANCE:
                ratios.append(float(np.clip(obs / max(pred, 1e-6), *GAIN_RANGE)))
        return float(np.exp(np.mean(np.log(ratios)))) if ratios else 1.0

    def aim(self, pose: Pose2D, table: Optional[TableBounds] = None, reach: float = math.inf) -> Goal:
        """The goal to plan the next push for, from `pose`: the true goal, corrected by the slide ratio of the pushes
        so far when adapting. A goal farther than one push of `reach` (m) slides is split into legs of at most
        LEG_REACH x reach: the aim is then the end of the first leg, an intermediate goal of any yaw, and the
        remaining pushes do the rest. A corrected aim stays on `table`, so the correction never turns a reachable
        goal into a refusal."""
        far = float(np.linalg.norm(self.goal.pose.xy - pose.xy))
        legs = math.ceil(far / (LEG_REACH * reach)) if math.isfinite(reach) else 1
        # more legs than pushes left: the goal itself, which the planner refuses with the reason
        if far - self.goal.position_tolerance > reach and 1 < legs <= self.max_pushes - len(self.steps):
            xy = self._on_table(pose.xy + (self.goal.pose.xy - pose.xy) / legs, table)
            return Goal(Pose2D(float(xy[0]), float(xy[1]), self.goal.pose.yaw),
                        max(self.goal.position_tolerance, LEG_TOLERANCE * far / legs), math.pi,
                        self.goal.yaw_symmetry)
        if not self.adapt or not self.steps:
            return self.goal
        g = self.gain
        delta = (self.goal.pose.xy - pose.xy) / g
        dist = float(np.linalg.norm(delta))
        if dist > reach:
            delta = delta * (reach / dist)
        xy = self._on_table(pose.xy + delta, table)
        return Goal(Pose2D(float(xy[0]), float(xy[1]), self.goal.pose.yaw), self.goal.position_tolerance / g,
                    self.goal.yaw_tolerance, self.goal.yaw_symmetry)

    @staticmethod
    def _on_table(xy: np.ndarray, table: Optional[TableBounds]) -> np.ndarray:
        if table is None:
            return xy
        return np.clip(xy, [table.x_min, table.y_min], [table.x_max, table.y_max])

    # ------------------------------------------------------------------------------------------ updates
    def record(self, start: Pose2D, predicted: Pose2D, observed: Pose2D, toppled: bool) -> PushStep:
        pos_err, yaw_err = goal_errors(observed, self.goal)
        step = PushStep(start, predicted, observed, bool(toppled), pos_err, yaw_err)
        self.steps.append(step)
        return step
