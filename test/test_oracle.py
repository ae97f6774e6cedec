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
"""The bench's ceiling: the planner over the true simulator predicts what executing its push does."""
from __future__ import annotations

import math

import numpy as np
import pytest

from physdyn_ros.planning import Goal, PlannerConfig, Pose2D, PushPlanner
from physdyn_ros.planning.closed_loop import execute, observe, push_to_goal
from physdyn_ros.planning.sim_model import ExactSimModel

ORACLE = PlannerConfig(time_budget=120.0, samples=24, max_iterations=2, robust_candidates=2, robust_samples=2,
                       tip_check=False, seed=0)


@pytest.fixture()
def sim():
    from physdyn_ros.sim import SimConfig, Simulator

    with Simulator(SimConfig(collision="parts")) as s:
        yield s


@pytest.mark.parametrize("category, index, yaw", [("box", 3, 0.4), ("mug", 2, -1.0), ("pybullet_data", 1, 2.0)])
def test_the_oracle_predicts_the_executed_push(sim, category, index, yaw):
    """Its roll-out is the execution: the impulse the planner's hull velocities stand for, on the true body, in
    the world restored to the state the push starts from (what remains: closed_loop.settle after the record)."""
    from physdyn_ros.shapes import resolve_shape

    sim.spawn(resolve_shape(category, index), xy=(0.0, 0.0), yaw=yaw)
    obs = observe(sim)
    with ExactSimModel(sim) as model:
        plan = PushPlanner(model, ORACLE).plan(obs.cloud, obs.pose, Goal(Pose2D(0.12, 0.05, yaw + 0.3)),
                                               mass=sim.mass)
    execute(sim, plan)
    after = observe(sim)
    assert np.linalg.norm(after.pose.xy - plan.final_pose.xy) < 0.001, plan.message
    assert abs(math.remainder(after.pose.yaw - plan.final_pose.yaw, 2 * math.pi)) < math.radians(0.5)
    assert not after.toppled


def test_the_oracle_sees_a_tall_box_topple(sim):
    """A fast high push tips a 4 x 4 x 16 cm box over: the roll-out says so (probability 1), a slow one not."""
    from physdyn_ros.planning import body_from_cloud
    from physdyn_ros.shapes.procedural import make_procedural

    sim.spawn(make_procedural("box", 3, seed=0), scale=(0.04 / 0.1, 0.04 / 0.1, 0.16 / 0.1), xy=(0.0, 0.0))
    obs = observe(sim)
    body = body_from_cloud(obs.cloud, mass=sim.mass)
    lo, hi = body.height_range(0.0, 1.0)
    d = np.array([[1.0, 0.0]])
    contact, _ = body.contacts(d, np.zeros(1), np.array([hi - 0.01]))
    with ExactSimModel(sim) as model:
        code = model.encode(obs.cloud)
        out = []
        for speed in (0.1, 1.5):
            v = np.array([[speed, 0.0, 0.0]])
            out.append(float(model.rollout_batch(code, v, body.angular_velocity(v, contact), horizon=16)
                             .topple_prob.max()))
    assert out == [0.0, 1.0]
    assert np.allclose(observe(sim).position, obs.position) and not observe(sim).toppled  # the world restored


def test_the_oracle_closes_the_loop(sim):
    from physdyn_ros.shapes import resolve_shape

    sim.spawn(resolve_shape("box", 3), xy=(0.0, 0.0), yaw=0.2)
    with ExactSimModel(sim) as model:
        result = push_to_goal(sim, PushPlanner(model, ORACLE), Goal(Pose2D(0.15, -0.05, 0.5)), max_pushes=2,
                              mass=sim.mass)
    assert result.success, result.message


def test_a_camera_sees_one_side_and_the_loop_plans_from_it(sim):
    """With a view, observe keeps the points a camera in that direction sees (the far side hidden) and the closed
    loop plans from that cloud: bench_planning's --view, one depth camera as on a real robot."""
    from physdyn_ros.planning import AnalyticSlidingModel, PlanningError
    from physdyn_ros.shapes import resolve_shape

    sim.spawn(resolve_shape("box", 3), xy=(0.0, 0.0), yaw=0.2)
    camera = np.array([math.cos(math.radians(30.0)), 0.0, math.sin(math.radians(30.0))])
    whole = observe(sim)
    seen = observe(sim, view=camera).cloud
    assert 0.2 * len(whole.cloud) < len(seen) < 0.8 * len(whole.cloud)
    depth = (whole.cloud - whole.position) @ camera  # towards the camera
    assert np.mean((seen - whole.position) @ camera) > np.mean(depth) + 0.1 * np.ptp(depth)
    noisy = observe(sim, 0.002, np.random.default_rng(0), view=camera).cloud
    assert len(noisy) == len(seen) and 0.001 < np.std(noisy - seen) < 0.003
    clouds = []

    class Recording(PushPlanner):
        def plan(self, shape, *args, **kwargs):
            clouds.append(np.asarray(shape))
            raise PlanningError("recorded")

    result = push_to_goal(sim, Recording(AnalyticSlidingModel(0.5), ORACLE), Goal(Pose2D(0.15, 0.0, 0.0)),
                          view=camera)
    assert result.outcome == "refused" and len(clouds) == 1 and np.allclose(clouds[0], seen)
