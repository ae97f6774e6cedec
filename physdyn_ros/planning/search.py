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
"""The search behind PushPlanner.plan: one cross-entropy-method run over candidate pushes of one object.

The cross-entropy method (CEM) runs over four numbers per candidate push, (vx, vy, f, h): the horizontal
velocity of the COM, where the line of push passes the COM (a fraction f in [-1, 1] of the object's extent across
the push at that height) and the contact height h (a fraction of the heights the pusher can reach on this object,
config min/max_contact_height). The contact point is the first observed surface point on that line (planning.body),
and the angular velocity follows from the impulse there: every candidate is a push a single contact can make; a low
contact tips the object back against its topple. Each iteration rolls all candidates out with one `rollout_batch`
call and keeps the elite fraction; the first iteration puts up to 16 candidates (at most half) at the Coulomb-
sliding solution (`Search.analytic_seeds`: the speed sqrt(2 mu g d) toward the goal and, per contact height, the
offset whose spin turns the object to the goal's yaw under sliding; each seed and three jittered copies), the rest
around the straight-line guess, gentle and low pushes included; later ones sample a Gaussian fitted to the elites.
Iterations stop when the time budget would be exceeded by the next one (cost per rolled-out step is measured on the
fly). The learned model rolls out only the search horizon (`head_timing=False`: its topple probability over those
steps is the whole push's), not the 60 steps a timed prediction needs: several times the candidates per budget.

Robustness: the best `robust_candidates` distinct elites are rolled out again under `robust_samples` small
perturbations each (speed, direction, offset, height: what a robot's execution and the perception get wrong).
The push whose perturbed outcomes cost least on average, and whose topple probability under that noise (the
mean over the push and its perturbations) stays under the limit, wins; its spread (RMS distance of the
perturbed rest positions from the nominal one) and that probability are reported. When none of them is safe
under that noise (a search that converged at the edge of the topple limit), the best pushes of the whole search
whose own risk lies under half the limit are checked the same way before the plan is refused. The mean, not
the worst perturbed push, is held to the limit: one unlucky perturbation of an otherwise safe push would refuse
objects the closed loop moves, without fewer topples. With an ensemble (`others`: further models and their codes of
the object) the check also rolls each push and its perturbations out on every member: a roll-out's topple
probability is then the highest member's, the robust cost the mean over every member's outcomes, and the spread
counts the members' rest positions too. The search itself stays on the first model (the members cost only the
check's roll-outs).

Cost of a candidate (lower is better), from its predicted final state:
    (position error / position tolerance)^2 + (yaw error / yaw tolerance)^2 (yaw ignored if tolerance >= pi or
      the object looks the same at every yaw; modulo 2 pi / k for a k-fold symmetric one: Goal.yaw_error)
    + (final speed / 0.1 m/s)^2, that speed taken from the last step's displacement (a trajectory still moving
      at the horizon has not reached its final pose)
    + 2 * topple probability + 1000 if the topple probability exceeds the limit or the COM leaves the table.

When no safe push reaches the goal, the safe push that gets closest wins (the closed loop pushes again).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from ..conventions import GRAVITY
from ..learn.baselines import horizontal_radius
from ..learn.prior import MIN_RADIUS
from ..predictor import Predictor, Trajectory, TrajectoryBatch
from .body import BodyError, PushBody, body_from_cloud
from .models import DynamicsModel
from .physics_check import PhysicsCheck
from .types import Goal, PlannerConfig, PlanningError, Pose2D, yaw_of

__all__ = ["INFEASIBLE", "MOVING_SCALE", "Candidate", "Search", "StepCost", "final_speed", "tip_probability"]

#: Penalty added to candidates that break a hard limit (topple probability, table edge).
INFEASIBLE = 1000.0
#: Final speed (m/s) that costs as much as one tolerance of position error.
MOVING_SCALE = 0.1


#: Tipping energy ratio at which tip_probability is 1 - 1/e, chosen so that the planner's default topple limit
#: separates the pushes that topple a tall box in pybullet from those that do not
#: (test_planning.py::test_tip_estimate_agrees_with_pybullet).
TIP_SCALE = 0.6


def tip_probability(ratio: np.ndarray) -> np.ndarray:
    """Topple risk from PushBody.tip_ratios: 1 - exp(-(r / TIP_SCALE)^2) (0.26 at r = 0.33, 0.50 at r = 0.5)."""
    return 1.0 - np.exp(-(np.asarray(ratio) / TIP_SCALE) ** 2)


def final_speed(positions: np.ndarray, dt: float) -> np.ndarray:
    """Horizontal speed (B,) over the last step of trajectories (B, T, 3), from the displacement.

    Not the fed-back velocity: the learned model's velocity channel can keep an offset after its predicted pose
    has stopped, which would make every short corrective push look unfinished.
    """
    return np.linalg.norm(positions[:, -1, :2] - positions[:, -2, :2], axis=-1) / dt


class StepCost:
    """Measured wall time of rolling one candidate out by one step (s): a running average kept by the planner
    across its searches, so that each search sizes its batches to the time left from the start."""

    def __init__(self) -> None:
        self.seconds: Optional[float] = None  # None until the first batch was timed

    def update(self, per_step: float) -> None:
        self.seconds = per_step if self.seconds is None else 0.5 * self.seconds + 0.5 * per_step


@dataclass
class Candidate:
    """One rolled-out push of the search: its parameters, where it touches, what the model predicts, its cost."""

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
    worst_topple: float = 0.0  # highest topple probability over the push and its perturbed pushes
    spread: float = 0.0  # m, RMS distance of the perturbed rest positions from this push's
    worst_push: Optional[tuple[np.ndarray, np.ndarray]] = None  # (lin_vel, ang_vel) of its most toppling perturbation
    # share of toppled hull re-simulations, or the topple fusion's probability (planning.physics_check); -1: not
    # checked
    physics_topple: float = -1.0

    def risk(self, pessimistic: bool) -> float:
        """The topple risk held to the limit: the push's own and, once checked, the mean (or, pessimistic, the
        highest) over it and its perturbations, and the physics check's verdict."""
        return max(self.topple, self.worst_topple if pessimistic else self.robust_topple, self.physics_topple)

    @property
    def lin_vel(self) -> np.ndarray:
        return np.array([self.speed * self.direction[0], self.speed * self.direction[1], 0.0])

    @property
    def params(self) -> np.ndarray:
        return np.array([self.speed * self.direction[0], self.speed * self.direction[1], self.fraction,
                         self.height_fraction])


#: Finalists the physics check always looks at before a refusal, even past the time budget.
PHYSICS_MIN = 3
#: Calm pushes of the whole search the physics check may fall back on.
PHYSICS_POOL = 8
#: Speeds, shares of the best push's, of the gentler pushes the physics check tries when that one tips the hull.
GENTLER = (0.75, 0.55, 0.4)

#: Perturbations of the robustness check (standard deviations): relative speed, direction (rad), offset
#: fraction, height (m).
PERTURB_SPEED, PERTURB_ANGLE, PERTURB_FRACTION, PERTURB_HEIGHT = 0.08, math.radians(4.0), 0.08, 0.01


class Search:
    """One CEM run (state shared by the iterations and the robustness check)."""

    def __init__(self, model: DynamicsModel, step_cost: StepCost, code: Any, body: PushBody, start: Pose2D,
                 goal: Goal, cfg: PlannerConfig, horizon: int, t0: float, physics: Optional[PhysicsCheck] = None,
                 others: Sequence[tuple[DynamicsModel, Any]] = ()) -> None:
        self.model, self.step_cost, self.code, self.body = model, step_cost, code, body
        self.others = list(others)  # (model, its code): the ensemble's other members, for the robustness check
        self.start, self.goal, self.cfg, self.horizon, self.t0 = start, goal, cfg, horizon, t0
        self.physics = physics
        self.fused = False  # the physics check's verdicts are the topple fusion's (_physics_checked)
        self.deadline = t0 + cfg.time_budget
        robust = cfg.robust_candidates > 0 and cfg.robust_samples > 0
        share = (cfg.robust_share if robust else 0.0) + (cfg.physics_share if physics is not None else 0.0)
        self.cem_deadline = t0 + cfg.time_budget * (1.0 - share)
        self.rng = np.random.default_rng(cfg.seed)
        self.iterations = 0
        self.rollouts = 0
        self.checked = False
        self.seen: list[Candidate] = []  # every candidate of the CEM iterations
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
        (spin-slide coupling, tilt): a CEM started only around the straight push needs many more iterations to
        find pushes within tolerance, more than a planning budget allows."""
        cfg = self.cfg
        speed = self.speed0
        d = np.array([math.cos(self.heading), math.sin(self.heading)])
        hf = (np.arange(heights) + 0.5) / heights
        if self.goal.ignores_yaw:
            return np.array([[speed * d[0], speed * d[1], 0.0, h] for h in hf])
        turn = self.goal.turn_from(self.start.yaw)  # to the nearest yaw the object's symmetry makes the goal's
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

    def _rollout(self, model: DynamicsModel, code: Any, v: np.ndarray, w: np.ndarray) -> TrajectoryBatch:
        """One model's roll-outs of the pushes (v, w) from the start over the search horizon."""
        p0 = np.array([self.start.x, self.start.y, self.z0])
        extra = {"head_timing": False} if isinstance(model, Predictor) else {}
        try:
            return model.rollout_batch(code, v, w, horizon=self.horizon, positions=p0, **extra)
        except ValueError as exc:  # e.g. a shape code from another model
            raise PlanningError(f"the dynamics model refused the request: {exc}") from None

    def _scored(self, batch: TrajectoryBatch, v: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, ...]:
        """Search.costs of `batch`, with the tipping estimate of the pushes (v, w) and the spin limit."""
        tip = self.body.tip_ratios(v, w, self.cfg.friction) if self.cfg.tip_check else None
        costs, pos_err, yaw_err, topple, off = self.costs(batch, tip)
        return (costs + INFEASIBLE * (np.linalg.norm(w, axis=1) > self.cfg.max_spin), pos_err, yaw_err, topple,
                off)

    def evaluate(self, params: np.ndarray, keep: bool = True) -> list[Candidate]:
        """Roll out candidate pushes (n, 4); keep: remember them in self.seen (the robustness fallback's pool)."""
        d, s, f, hf = self._project(params)
        contacts, e = self.body.contacts(d, f, self.h_lo + hf * (self.h_hi - self.h_lo))
        v = np.concatenate([s[:, None] * d, np.zeros((len(s), 1))], axis=1)
        w = self.body.angular_velocity(v, contacts)
        t = time.perf_counter()
        batch = self._rollout(self.model, self.code, v, w)
        self.step_cost.update((time.perf_counter() - t) / (len(s) * self.horizon))
        self.rollouts += len(s)
        costs, pos_err, yaw_err, topple, off = self._scored(batch, v, w)
        cands = [Candidate(float(costs[i]), d[i], float(s[i]), float(f[i]), float(hf[i]), float(e[i]), contacts[i],
                            w[i], float(pos_err[i]), float(yaw_err[i]), float(topple[i]), bool(off[i]), batch[i])
                 for i in range(len(s))]
        if keep:
            self.seen.extend(cands)
        return cands

    def costs(self, batch: TrajectoryBatch, tip: Optional[np.ndarray] = None) -> tuple[np.ndarray, ...]:
        """(cost, position error, yaw error, topple probability, off the table) per roll-out of `batch` (the cost
        of the module docstring; `tip`: PushBody.tip_ratios, counted as topple risk too)."""
        g, cfg = self.goal, self.cfg
        final = batch.positions[:, -1, :2]
        pos_err = np.linalg.norm(final - g.pose.xy, axis=1)
        yaw_err = np.asarray(g.yaw_error(self.start.yaw + yaw_of(batch.orientations[:, -1])))  # folded: symmetry
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
        per = self.step_cost.seconds
        if per is None:
            return min(n, 32)
        left = deadline - time.perf_counter()
        fit = int(0.85 * left / max(per * self.horizon, 1e-9))
        return min(n, fit)

    # -- CEM -----------------------------------------------------------------------------------------------
    def run(self) -> Candidate:
        """The CEM iterations within the budget, then the robustness check: the winning candidate."""
        cfg = self.cfg
        lo = np.array([-cfg.max_speed, -cfg.max_speed, -cfg.max_offset_fraction, 0.0])
        hi = np.array([cfg.max_speed, cfg.max_speed, cfg.max_offset_fraction, 1.0])
        std_floor = np.array([0.01, 0.01, 0.02, 0.02])
        best: Optional[Candidate] = None
        elites: list[Candidate] = []
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

    def robust(self, elites: list[Candidate], best: Candidate) -> Candidate:
        """Re-check the best distinct elites under perturbed execution; the most robust safe one wins. When none
        of them is safe under that noise (the search converged on risky pushes), the best pushes of the whole
        search whose own topple risk lies under half the limit are checked the same way."""
        cfg = self.cfg
        k, m = cfg.robust_candidates, cfg.robust_samples
        if k == 0 or m == 0:
            if self.physics is not None and best.cost < INFEASIBLE:  # the physics check still has the last word
                return self._physics_checked([best] if best.risk(cfg.pessimistic) <= cfg.max_topple_probability
                                             else [], [best])
            return best
        chosen = _distinct(elites, k)
        if not chosen:
            return best
        self._perturb(chosen, m)
        safe = [c for c in chosen if c.risk(cfg.pessimistic) <= cfg.max_topple_probability]
        if not safe:
            calm = sorted((c for c in self.seen if c.topple <= 0.5 * cfg.max_topple_probability), key=lambda c: c.cost)
            # within the budget if it allows (at least one candidate: a refusal must have looked)
            room = max(1, min(k, self._batch_size(self.deadline) // m))
            fallback = [c for c in _distinct(calm, k) if all(c is not o for o in chosen)][:room]
            if fallback:
                self._perturb(fallback, m)
                safe = [c for c in fallback if c.risk(cfg.pessimistic) <= cfg.max_topple_probability]
                chosen += fallback
        if self.physics is not None:
            return self._physics_checked(safe, chosen)
        return min(safe or chosen, key=lambda c: c.robust_cost)

    def _physics_checked(self, safe: list[Candidate], chosen: list[Candidate]) -> Candidate:
        """The most robust push the hull's physics also finds safe (planning.physics_check), checked in the order
        of preference until one passes: the robustness check's two best safe pushes, the best push slowed down
        (Search._gentler), the other safe pushes, then the calm pushes of the whole
        search (the model's topple risk under half the limit, each a different push, closest to the goal first;
        each goes through the robustness check first). Checking goes on past the budget for at least PHYSICS_MIN
        pushes and at most half a budget more (a refusal must have looked). When none passes, the checked push of
        lowest risk (the planner refuses it with the reason)."""
        assert self.physics is not None
        cfg = self.cfg
        points = self.body.points + self.body.com
        solid = None
        if cfg.whole_cloud and self.body.source == "hull":
            try:  # the push as executed: the same impulses, on the solid the cloud encloses
                solid = body_from_cloud(points, cfg.density, self.body.mass, whole=True)
            except BodyError:
                solid = None  # too few or flat points: the hull's own mass model

        def executed(push: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
            return push if solid is None else (push[0], self.body.reweigh(solid, push[0], push[1])[0])

        hull = self.physics.encode(points, solid)
        # the fusion was fitted on the solid's runs: with a hull only (one camera's view) the share of toppled
        # runs vetoes
        self.fused = self.physics.fusion is not None and solid is not None
        limit = cfg.max_topple_probability
        calm = sorted((c for c in self.seen if c.topple <= 0.5 * limit and c.cost < INFEASIBLE), key=lambda c: c.cost)
        safe = sorted(safe, key=lambda c: c.robust_cost)
        gentler = sorted(self._gentler(min(chosen, key=lambda c: c.robust_cost)), key=lambda c: c.cost)
        pool = safe[:2] + gentler + safe[2:]
        pool += [c for c in _diverse(calm, PHYSICS_POOL) if all(c is not o for o in pool + chosen)]
        hard = self.deadline + 0.5 * cfg.time_budget
        checked: list[Candidate] = []
        for c in pool:
            now = time.perf_counter()
            if checked and (now > hard or (len(checked) >= PHYSICS_MIN and now > self.deadline)):
                break  # a plan is never accepted unchecked: the first push is checked whatever the time
            if c.worst_push is None and cfg.robust_candidates > 0 and cfg.robust_samples > 0:
                self._perturb([c], cfg.robust_samples)
                if c.risk(cfg.pessimistic) > limit:
                    continue
            if self.fused:  # the model's own whole-push probability, as the weights were fitted (c.topple also
                # counts the tipping estimate)
                c.physics_topple = self.physics.fused_topple(hull, executed((c.lin_vel, c.ang_vel)),
                                                             float(c.trajectory.topple_prob.max()), self.horizon)
            else:
                worst = None if c.worst_push is None else executed(c.worst_push)
                c.physics_topple = self.physics.topple_share(hull, executed((c.lin_vel, c.ang_vel)), worst,
                                                             self.horizon, limit)
            checked.append(c)
            if c.risk(cfg.pessimistic) <= limit:
                return c
        return min(checked or chosen, key=lambda c: (c.risk(cfg.pessimistic), c.robust_cost))

    def _gentler(self, best: Candidate) -> list[Candidate]:
        """The push `best` slower (GENTLER speeds) at its own contact height and at the lowest: shorter pushes
        that tip less, for the closed loop to push again (those within the model's topple limit only)."""
        speeds = np.array(GENTLER)
        p = np.tile(best.params, (2 * len(speeds), 1))
        p[:, :2] *= np.tile(speeds, 2)[:, None]
        p[len(speeds):, 3] = 0.0
        return [c for c in self.evaluate(p, keep=False) if c.cost < INFEASIBLE]

    def _perturb(self, chosen: list[Candidate], m: int) -> None:
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
        # (models, K, 1 + m): each push and its perturbations, as the search model and every other member see them
        flat = [p for i, c in enumerate(chosen) for p in [c] + perturbed[i * m:(i + 1) * m]]
        shape = (1, len(chosen), 1 + m)
        cost = np.array([p.cost for p in flat]).reshape(shape)
        topple = np.array([p.topple for p in flat]).reshape(shape)
        finals = np.array([p.trajectory.positions[-1, :2] for p in flat]).reshape(shape + (2,))
        if self.others:  # the very pushes the search model rolled out
            v, w = np.array([p.lin_vel for p in flat]), np.array([p.ang_vel for p in flat])
            for model, code in self.others:
                batch = self._rollout(model, code, v, w)
                scored = self._scored(batch, v, w)
                self.rollouts += len(v)
                cost = np.concatenate([cost, scored[0].reshape(shape)])
                topple = np.concatenate([topple, scored[3].reshape(shape)])
                finals = np.concatenate([finals, batch.positions[:, -1, :2].reshape(shape + (2,))])
        for i, c in enumerate(chosen):
            costs = np.minimum(cost[:, i], INFEASIBLE)
            costs[0, 0] = c.cost
            c.robust_cost = float(np.mean(costs))
            # the push's topple probability under execution noise: the mean over it and its perturbations, each
            # the highest of the ensemble's members (the pessimistic side of their disagreement)
            risk = topple[:, i].max(axis=0)
            c.robust_topple = float(np.mean(risk))
            c.worst_topple = float(risk.max())
            worst = perturbed[i * m + int(np.argmax(risk[1:]))]
            c.worst_push = (worst.lin_vel, worst.ang_vel)
            # RMS distance from this push's rest position of the other outcomes: perturbed pushes and members
            gaps = np.sum((finals[:, i] - c.trajectory.positions[-1, :2]) ** 2, axis=-1).ravel()[1:]
            c.spread = float(np.sqrt(np.mean(gaps)))


def _diverse(cands: list[Candidate], k: int) -> list[Candidate]:
    """The first k candidates each clearly another push than those before it: speed by 5 cm/s or direction,
    offset or height fraction by 0.1 (cands sorted by preference)."""
    chosen: list[Candidate] = []
    scale = np.array([0.05, 0.05, 0.1, 0.1])
    for c in cands:
        if all(np.abs((c.params - o.params) / scale).max() > 1.0 for o in chosen):
            chosen.append(c)
            if len(chosen) == k:
                break
    return chosen


def _distinct(cands: list[Candidate], k: int) -> list[Candidate]:
    """The first k feasible candidates each a little different from those before it (cands sorted by cost)."""
    chosen: list[Candidate] = []
    for c in cands:
        if c.cost >= INFEASIBLE:
            break
        if all(np.abs(c.params - o.params).max() > 1e-3 for o in chosen):
            chosen.append(c)
        if len(chosen) == k:
            break
    return chosen
