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
"""Yaw goals the object can show: the cloud's rotational symmetry about its up axis, in the planner and the loop."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from physdyn_ros.planning import AnalyticSlidingModel, Goal, PlannerConfig, Pose2D, PushPlanner
from physdyn_ros.planning.session import PushSession, goal_errors
from physdyn_ros.planning.symmetry import CONTINUOUS, NONE, yaw_symmetry
from physdyn_ros.planning.types import PlanningError, fold_yaw

NOISE = 0.002  # m, the depth sensor noise the thresholds are meant to bear


def _posed(pts: np.ndarray, yaw: float, xy=(0.0, 0.0)) -> np.ndarray:
    """Points (object frame, z up from the table) turned by yaw and moved to xy."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = pts @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return out + np.array([xy[0], xy[1], 0.0])


def cylinder(radius=0.04, height=0.15, n=1024, seed=0) -> np.ndarray:
    """Area-uniform points on a closed upright cylinder."""
    rng = np.random.default_rng(seed)
    side, cap = 2 * math.pi * radius * height, math.pi * radius ** 2
    on_side = rng.random(n) < side / (side + 2 * cap)
    a = rng.uniform(0, 2 * math.pi, n)
    r = np.where(on_side, radius, radius * np.sqrt(rng.random(n)))
    z = np.where(on_side, rng.uniform(0, height, n), np.where(rng.random(n) < 0.5, 0.0, height))
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def ball(radius=0.05, n=1024, seed=0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True) + np.array([0.0, 0.0, radius])


def box(half=(0.05, 0.035, 0.04), n=1024, seed=0) -> np.ndarray:
    """Area-uniform points on a box resting on the table."""
    rng = np.random.default_rng(seed)
    h = np.asarray(half)
    areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    pts = rng.uniform(-1.0, 1.0, (n, 3))
    pts[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    return pts * h + np.array([0.0, 0.0, h[2]])


def prism(sides=3, radius=0.05, height=0.08, n=1024, seed=0) -> np.ndarray:
    """Points on the side faces and caps of a regular prism (perimeter-uniform sides, caps by rejection)."""
    rng = np.random.default_rng(seed)
    corners = radius * np.stack([np.cos(2 * np.pi * np.arange(sides + 1) / sides),
                                 np.sin(2 * np.pi * np.arange(sides + 1) / sides)], axis=1)
    k, t = rng.integers(0, sides, n), rng.random(n)
    xy = corners[k] + t[:, None] * (corners[k + 1] - corners[k])
    z = rng.uniform(0, height, n)
    cap = rng.random(n) < 0.3  # caps: points inside the polygon (shrink a side point toward the centre)
    xy[cap] *= np.sqrt(rng.random(cap.sum()))[:, None]
    z[cap] = np.where(rng.random(cap.sum()) < 0.5, 0.0, height)
    return np.column_stack([xy, z])


def mug(n=1024, seed=0) -> np.ndarray:
    """A cylinder with a handle: a loop of points beside it."""
    body = cylinder(0.04, 0.1, int(0.85 * n), seed)
    rng = np.random.default_rng(seed + 1)
    m = n - len(body)
    a, b = rng.uniform(-math.pi / 2, math.pi / 2, m), rng.uniform(0, 2 * math.pi, m)
    ring = np.stack([0.04 + 0.03 * np.cos(a) + 0.006 * np.cos(b) * np.cos(a),
                     0.006 * np.sin(b), 0.05 + 0.03 * np.sin(a) + 0.006 * np.cos(b) * np.sin(a)], axis=1)
    return np.concatenate([body, ring])


def catalogue(category: str, index: int) -> np.ndarray:
    from physdyn_ros.shapes import make_procedural

    shape = make_procedural(category, index, seed=0)
    return np.asarray(shape.points, dtype=np.float64) - np.array([0.0, 0.0, float(shape.vertices[:, 2].min())])


CASES = {
    "cylinder": (cylinder(), CONTINUOUS),
    "wide low cylinder": (cylinder(0.12, 0.05, seed=1), CONTINUOUS),
    "ball": (ball(), CONTINUOUS),
    "bottle": (catalogue("bottle", 3), CONTINUOUS),
    "rectangular box": (box(), 2),
    "square box": (box((0.04, 0.04, 0.06)), 4),
    "triangular prism": (prism(3), 3),
    "hexagonal prism": (prism(6, 0.08, 0.05), 6),
    "mug": (mug(), NONE),
    "catalogue mug": (catalogue("mug", 1), NONE),
    "stretched 12-gon": (catalogue("prism", 2), 2),  # an oval in plan: 2-fold, though close to every rotation
}


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("noise", [0.0, NOISE])
def test_symmetry_of_clean_and_noisy_clouds(name, noise):
    pts, want = CASES[name]
    rng = np.random.default_rng(7)
    cloud = _posed(pts, yaw=0.7, xy=(0.3, -0.2))  # an axis away from the origin, a turned object
    if noise:
        cloud = cloud + rng.normal(0.0, noise, cloud.shape)
    assert yaw_symmetry(cloud) == want


@pytest.mark.parametrize("name", ["cylinder", "ball", "square box", "rectangular box"])
def test_a_partial_view_keeps_the_yaw_goal(name):
    """One side of an object (a camera's view) does not map onto itself: the cautious answer, no symmetry."""
    pts = _posed(CASES[name][0], 0.3)
    view = pts[pts[:, 0] > -0.3 * np.abs(pts[:, 0]).max()]  # the camera on +x sees a little past the middle
    noisy = view + np.random.default_rng(3).normal(0.0, NOISE, view.shape)
    assert yaw_symmetry(view) == NONE and yaw_symmetry(noisy) == NONE


def test_degenerate_clouds_are_not_symmetric():
    assert yaw_symmetry(np.zeros((3, 3))) == NONE
    assert yaw_symmetry(np.full((100, 3), np.nan)) == NONE
    assert yaw_symmetry(np.zeros((100, 3))) == NONE


def test_fold_and_goal_rules():
    assert fold_yaw(0.3, None) == 0.3 and fold_yaw(2.5, 1) == 2.5
    assert fold_yaw(2.5, 0) == 0.0
    assert fold_yaw(math.radians(100), 4) == pytest.approx(math.radians(10))
    assert fold_yaw(math.radians(170), 2) == pytest.approx(math.radians(10))
    x = 0.7  # within half a period: bit for bit the plain error
    assert fold_yaw(x, 2) == x and fold_yaw(np.array([x]), 2)[0] == x
    g = Goal(Pose2D(0.1, 0.0, 0.0), 0.02, math.radians(10), yaw_symmetry=4)
    assert g.yaw_error(math.radians(92)) == pytest.approx(math.radians(2))
    assert g.turn_from(math.radians(-80)) == pytest.approx(math.radians(-10))
    assert not g.ignores_yaw and Goal(Pose2D(0, 0, 0), 0.02, math.radians(50), yaw_symmetry=4).ignores_yaw
    assert Goal(Pose2D(0, 0, 0), yaw_symmetry=0).ignores_yaw
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(PlanningError, match="yaw_symmetry"):
            Goal(Pose2D(0, 0, 0), yaw_symmetry=bad)


# the sliding model knows no topples: the hull's physics would veto its fast pushes of a tall cylinder
FAST = PlannerConfig(time_budget=30.0, samples=64, max_iterations=4, seed=1, physics_check=False)


@pytest.fixture(scope="module")
def planner() -> PushPlanner:
    return PushPlanner(AnalyticSlidingModel(friction=0.5), FAST)


def test_the_planner_ignores_the_yaw_of_an_upright_cylinder():
    cloud = _posed(cylinder(), 0.0)
    goal = Goal(Pose2D(0.15, 0.05, math.pi), 0.02, math.radians(10))  # half a turn that no cloud shows
    plan = PushPlanner(AnalyticSlidingModel(friction=0.5), FAST).plan(cloud, Pose2D(0.0, 0.0, 0.0), goal)
    assert plan.goal.yaw_symmetry == CONTINUOUS and plan.goal.ignores_yaw
    assert plan.within_tolerance and plan.yaw_error == 0.0
    assert "yaw goal ignored: the cloud is rotationally symmetric about its up axis" in plan.message
    # the same push as a goal that ignores the yaw outright: the yaw costs nothing, no spin is sought
    free = PushPlanner(AnalyticSlidingModel(friction=0.5), FAST).plan(  # fresh: the same first batch
        cloud, Pose2D(0.0, 0.0, 0.0), Goal(Pose2D(0.15, 0.05, 0.0), 0.02, math.pi))
    np.testing.assert_array_equal(plan.lin_vel, free.lin_vel)


def test_the_planner_takes_a_square_box_yaw_modulo_90_deg(planner):
    cloud = _posed(box((0.04, 0.04, 0.03)), 0.0)
    goal = Goal(Pose2D(0.15, 0.0, math.radians(95)), 0.02, math.radians(10))
    plan = planner.plan(cloud, Pose2D(0.0, 0.0, 0.0), goal)
    assert plan.goal.yaw_symmetry == 4
    assert "yaw goal taken modulo 90 deg: the cloud is 4-fold symmetric about its up axis" in plan.message
    assert plan.yaw_error <= math.radians(10) and plan.within_tolerance
    # a turn of 5 deg, not 95 deg: Coulomb sliding asks sqrt(2 mu g |turn| / r) of the spin, ~5 vs ~21 rad/s
    assert abs(plan.ang_vel[2]) < 10.0


def test_a_given_symmetry_and_detect_symmetry_off_are_respected(planner):
    cloud = _posed(cylinder(), 0.0)
    goal = Goal(Pose2D(0.15, 0.05, 1.0), 0.02, math.radians(10), yaw_symmetry=NONE)
    assert planner.plan(cloud, Pose2D(0, 0, 0), goal).goal.yaw_symmetry == NONE
    off = replace(FAST, detect_symmetry=False)
    plan = planner.plan(cloud, Pose2D(0, 0, 0), replace(goal, yaw_symmetry=None), config=off)
    assert plan.goal.yaw_symmetry is None and "yaw goal" not in plan.message


def test_an_already_reached_symmetric_goal_needs_no_push(planner):
    cloud = _posed(cylinder(), 0.0, (0.1, 0.1))
    plan = planner.plan(cloud, Pose2D(0.1, 0.1, 0.0), Goal(Pose2D(0.105, 0.1, 2.0)))
    assert plan.rollouts == 0 and plan.within_tolerance and "yaw goal ignored" in plan.message


def test_the_session_folds_the_yaw_the_same_way():
    session = PushSession(Goal(Pose2D(0.2, 0.0, math.radians(95)), 0.02, math.radians(10)), max_pushes=2)
    here = Pose2D(0.2, 0.0, math.radians(3))
    assert not session.within(here)  # unknown symmetry: the yaw counts
    assert session.observe_shape(_posed(box((0.04, 0.04, 0.03)), 0.0, (0.2, 0.0))) == 4
    assert session.within(here) and goal_errors(here, session.goal)[1] == pytest.approx(math.radians(2))
    assert session.check(here, False).outcome == "reached"
    assert session.aim(Pose2D(0.0, 0.0, 0.0)).yaw_symmetry == 4  # aims carry it to the planner
    assert session.aim(Pose2D(-0.6, 0.0, 0.0), reach=0.3).yaw_symmetry == 4  # legs too
    session.observe_shape(_posed(cylinder(), 0.0))  # decided once per episode: a later cloud changes nothing
    assert session.goal.yaw_symmetry == 4
