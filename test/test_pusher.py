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
"""The push_to_goal action over DDS: sim -> perception -> predictor -> pusher, the shipped model, real pybullet.

A box is pushed to a goal closed loop; the feedback shows each stage and a contact point on the object's
surface; bad goals end with an outcome and the reason; a cancelled goal stops before its push; a robot that
never executes its push times out with the reason. The node keeps serving after every one of them.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.action import ActionClient
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter

from physdyn_ros.action import PushToGoal
from physdyn_ros.msg import ObjectState
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.nodes.pusher_node import PusherNode
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.ros.qos import STATE_QOS
from physdyn_ros.ros.convert import pose, yaw_quaternion
from test_nodes_support import Spinner, wait_for


def goal_msg(x: float, y: float, yaw: float = 0.0, **fields) -> PushToGoal.Goal:
    g = PushToGoal.Goal(**{"object_id": "object", **fields})
    g.header.frame_id = "world"
    g.goal_pose = pose([x, y, 0.0], yaw_quaternion(yaw))
    return g


def surface_mm(sim, pose_msg, point) -> float:
    """mm from a table-frame point to the sim object's mesh posed at pose_msg."""
    from scipy.spatial.transform import Rotation

    from physdyn_ros.shapes.core import surface_distance

    shape, scale = sim.sim.shape, np.asarray(sim.sim.scale)
    p, q = pose_msg.position, pose_msg.orientation
    local = Rotation.from_quat([q.x, q.y, q.z, q.w]).inv().apply(np.asarray(point) - [p.x, p.y, p.z])
    return 1e3 * float(surface_distance(np.asarray(shape.vertices) * scale, shape.faces, local)[0])


class Client:
    """Send goals from the test thread; feedback collected per goal."""

    def __init__(self, node) -> None:
        self.action = ActionClient(node, PushToGoal, "push_to_goal")
        self.feedback: list = []

    def send(self, goal: PushToGoal.Goal, timeout: float = 90.0, cancel_when=None):
        assert self.action.wait_for_server(timeout_sec=20.0), "push_to_goal server not available"
        self.feedback = []
        sent = self.action.send_goal_async(goal, feedback_callback=lambda m: self.feedback.append(m.feedback))
        assert wait_for(sent.done, 20.0), "goal not answered"
        handle = sent.result()
        assert handle.accepted
        if cancel_when is not None:
            assert wait_for(lambda: cancel_when(self.feedback), 30.0), [f.stage for f in self.feedback]
            handle.cancel_goal_async()
        result = handle.get_result_async()
        assert wait_for(result.done, timeout), "no result"
        return result.result().result


@pytest.fixture(scope="module")
def suite(rclpy_init):
    sim = SimNode(parameter_overrides=[Parameter("real_time_factor", value=0.0), Parameter("category", value="box"),
                                       Parameter("shape_seed", value=3), Parameter("publish_cloud_rate", value=5.0)])
    perception = PerceptionNode()
    # the action's mechanics are under test here, not the model's topple calibration (bench/bench_planning.py)
    # (and a planning budget that a loaded test machine still searches well with)
    predictor = PredictorNode(parameter_overrides=[Parameter("plan_max_topple_probability", value=0.6),
                                                   Parameter("plan_time_budget", value=0.6)])
    pusher = PusherNode(parameter_overrides=[Parameter("motion_timeout", value=3.0),
                                            Parameter("external_motion_timeout", value=1.0)])
    user = rclpy_init.create_node("pusher_user")
    states: list[ObjectState] = []
    user.create_subscription(ObjectState, "object_state", states.append, STATE_QOS)
    client = Client(user)
    with Spinner(sim, perception, predictor, pusher, user, threads=8):
        assert wait_for(lambda: predictor._features.get("object") and states, 30), perception.last_error
        yield sim, pusher, client, states


def test_push_to_goal_reaches_the_goal_with_contacts_on_the_surface(suite):
    sim, pusher, client, states = suite
    x0, y0, _ = sim.spawn_pose
    start_pose = states[-1].pose
    result = client.send(goal_msg(x0 + 0.12, y0 + 0.03, position_tolerance=0.03, yaw_tolerance=math.pi,
                                  max_pushes=4))
    trace = [(f.stage, round(f.contact_point.x, 3), round(f.contact_point.y, 3), round(f.impulse.x, 3),
              round(f.impulse.y, 3), round(f.predicted_rest_pose.position.x, 3),
              round(f.predicted_rest_pose.position.y, 3), round(f.observed_rest_pose.position.x, 3),
              round(f.observed_rest_pose.position.y, 3), round(f.position_error, 3)) for f in client.feedback]
    assert result.success and result.outcome == "reached", (result.message, trace)
    assert 1 <= result.pushes <= 4 and result.position_error <= 0.03
    # feedback (a topic) and the result (a service) are separate channels: the last feedback, published just
    # before the result, may reach the client after it
    assert wait_for(lambda: "rested" in [f.stage for f in client.feedback], 10), [f.stage for f in client.feedback]
    stages = [f.stage for f in client.feedback]
    assert stages[:2] == ["planning", "pushing"], stages
    pushed = [f for f in client.feedback if f.stage == "pushing"]
    assert len(pushed) == result.pushes
    # the first contact lies on the box's surface (its mesh posed where it rested): within 2 mm
    c = pushed[0].contact_point
    assert surface_mm(sim, start_pose, [c.x, c.y, c.z]) < 2.0 and c.z > 0.004, c
    assert pushed[0].topple_probability <= 0.6
    assert 0.0 <= pushed[0].success_probability <= 1.0  # the shipped model's spread calibration: an estimate


def test_bad_goals_end_with_the_reason_and_the_node_keeps_serving(suite):
    sim, pusher, client, states = suite
    cases = [(goal_msg(0.1, 0.0, object_id="nothing"), "invalid", "no object_state of 'nothing'"),
             (goal_msg(float("nan"), 0.0), "invalid", "not finite"),
             (goal_msg(0.1, 0.0, position_tolerance=-1.0), "invalid", "position_tolerance must be finite"),
             (goal_msg(5.0, 0.0), "refused", "off the table")]
    bad_frame = goal_msg(0.1, 0.0)
    bad_frame.header.frame_id = "camera"
    cases.append((bad_frame, "invalid", "not the table frame"))
    for goal, outcome, reason in cases:
        result = client.send(goal, timeout=30.0)
        assert not result.success and result.outcome == outcome and reason in result.message, result.message
    # a goal where the object already is: success without a push
    here = states[-1].pose.position
    result = client.send(goal_msg(here.x, here.y, yaw_tolerance=math.pi))
    assert result.success and result.pushes == 0 and result.outcome == "reached", result.message
    assert pusher.counts["invalid"] >= 4


def test_cancel_and_a_robot_that_never_pushes(suite):
    sim, pusher, client, states = suite
    here = states[-1].pose.position
    far = dict(execute_externally=True, yaw_tolerance=math.pi)
    # cancelled while planning: stops before the push
    result = client.send(goal_msg(here.x + 0.1, here.y, **far), cancel_when=lambda fb: fb)
    assert result.outcome == "cancelled" and result.pushes == 0, result.message
    # nobody executes the push: cancelled while waiting for it, before anything moved
    result = client.send(goal_msg(here.x + 0.1, here.y, **far),
                         cancel_when=lambda fb: any(f.stage == "pushing" for f in fb))
    assert result.outcome == "cancelled" and result.pushes == 0, result.message
    # not cancelled: the push never starts moving the object within external_motion_timeout
    result = client.send(goal_msg(here.x + 0.1, here.y, **far))
    assert result.outcome == "timeout" and "did not start moving" in result.message, result.message


def test_one_goal_at_a_time_and_deactivate_stops_a_goal(suite):
    sim, pusher, client, states = suite
    here = states[-1].pose.position
    pusher.set_parameters([Parameter("external_motion_timeout", value=30.0)])
    try:
        assert client.action.wait_for_server(timeout_sec=20.0)
        first = client.action.send_goal_async(goal_msg(here.x + 0.1, here.y, execute_externally=True,
                                                       yaw_tolerance=math.pi))
        assert wait_for(first.done, 20.0) and first.result().accepted
        second = client.action.send_goal_async(goal_msg(here.x + 0.1, here.y, yaw_tolerance=math.pi))
        assert wait_for(second.done, 20.0) and not second.result().accepted  # one pusher, one goal
        # the first waits for a robot that never pushes; deactivating the node ends it at once, with the reason
        assert wait_for(lambda: pusher._busy.locked(), 20.0)
        # asked before the goal ends: rclpy 7's action client registers a request only after sending it, so a
        # result that came back first would be dropped
        done = first.result().get_result_async()
        assert pusher.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
        assert wait_for(done.done, 10.0), "the goal did not stop on deactivate"
        result = done.result().result
        assert result.outcome == "invalid" and "inactive" in result.message, result.message
    finally:
        pusher.trigger_activate()
        pusher.set_parameters([Parameter("external_motion_timeout", value=1.0)])
    assert pusher.is_active


def test_a_goal_beyond_one_push_is_reached_in_legs(suite):
    """A goal farther than one push slides is reached in legs, not refused, when max_pushes allows several."""
    sim, pusher, client, states = suite
    here = states[-1].pose.position
    result = client.send(goal_msg(here.x - 0.5, here.y, position_tolerance=0.05, yaw_tolerance=math.pi,
                                  max_pushes=5), timeout=180.0)
    assert result.outcome != "refused", result.message
    pushed = [f for f in client.feedback if f.stage == "pushing"]
    assert result.pushes >= 2 and len(pushed) >= 2, result.message
    first = pushed[0].predicted_rest_pose.position
    assert 0.1 < here.x - first.x < 0.4, (here.x, first.x)  # the first push aims at an intermediate goal


def test_each_push_is_planned_from_the_rest_state_the_pusher_saw(suite):
    """The pusher plans from the state it saw the object rest in, not from plan_push's latest object_state:
    the predictor's executor may not have replaced a moving state yet when a push ends, and a plan for where the
    object was a frame ago put the contact centimetres off its surface (push_object refused it)."""
    from copy import deepcopy

    from physdyn_ros.planning import Goal, Pose2D

    sim, pusher, client, states = suite
    rest = deepcopy(states[-1])
    rest.pose.position.x += 0.03  # a rest pose that is not the latest object_state the predictor holds
    x, y = rest.pose.position.x, rest.pose.position.y
    plan = pusher._plan(PushToGoal.Goal(object_id="object"), Goal(Pose2D(x + 0.12, y, 0.0), 0.03, math.pi), rest)
    assert plan.success, plan.message
    first = plan.trajectory.states[0].pose.position
    assert (first.x, first.y) == pytest.approx((x, y), abs=1e-6)
