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
from rclpy.parameter import Parameter

from physdyn_ros.action import PushToGoal
from physdyn_ros.msg import ObjectState
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.nodes.pusher_node import PusherNode
from physdyn_ros.nodes.sim_node import STATE_QOS, SimNode
from physdyn_ros.ros.convert import pose, yaw_quaternion
from test_nodes_support import Spinner, wait_for


def goal_msg(x: float, y: float, yaw: float = 0.0, **fields) -> PushToGoal.Goal:
    g = PushToGoal.Goal(**{"object_id": "object", **fields})
    g.header.frame_id = "world"
    g.goal_pose = pose([x, y, 0.0], yaw_quaternion(yaw))
    return g


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
    sim, pusher, client, _ = suite
    x0, y0, _ = sim.spawn_pose
    result = client.send(goal_msg(x0 + 0.12, y0 + 0.03, position_tolerance=0.03, yaw_tolerance=math.pi,
                                  max_pushes=4))
    trace = [(f.stage, round(f.contact_point.x, 3), round(f.contact_point.y, 3), round(f.impulse.x, 3),
              round(f.impulse.y, 3), round(f.predicted_rest_pose.position.x, 3),
              round(f.predicted_rest_pose.position.y, 3), round(f.observed_rest_pose.position.x, 3),
              round(f.observed_rest_pose.position.y, 3), round(f.position_error, 3)) for f in client.feedback]
    assert result.success and result.outcome == "reached", (result.message, trace)
    assert 1 <= result.pushes <= 4 and result.position_error <= 0.03
    stages = [f.stage for f in client.feedback]
    assert stages[:2] == ["planning", "pushing"] and "rested" in stages, stages
    pushed = [f for f in client.feedback if f.stage == "pushing"]
    assert len(pushed) == result.pushes
    # the first contact lies on the box's surface: within 2 mm of the sim's surface samples at the start pose
    c = pushed[0].contact_point
    start = sim.sim.shape.points * np.asarray(sim.sim.scale)  # object frame; the box started at yaw 0
    surface = start + np.array([x0, y0, 0.0]) + np.array([0.0, 0.0, float(-start[:, 2].min())])
    gap = np.linalg.norm(surface - [c.x, c.y, c.z], axis=1).min()
    assert gap < 0.004 and c.z > 0.004, (gap, c)
    assert pushed[0].topple_probability <= 0.2


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
