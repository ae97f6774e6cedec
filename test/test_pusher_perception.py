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
"""push_to_goal on what the camera shows: on perception alone (state_source perception: the pusher and the
predictor read the perception node's tracked states, goals name its track ids, the sim is pushed at the contact
point without an id; only the test reads the sim's ground truth, to check where the object came to rest), and
with a yaw goal the object's cloud cannot show."""
from __future__ import annotations

import math

from rclpy.parameter import Parameter

from physdyn_ros.msg import ObjectState
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.nodes.pusher_node import PusherNode
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.ros.qos import STATE_QOS
from test_nodes_support import Spinner, wait_for
from test_pusher import Client, goal_msg


def box_on_camera(rclpy_init, user_name: str, plan_time_budget: float, motion_timeout: float) -> tuple:
    """A box on the sim's 15 Hz camera, the four nodes on state_source perception (perception's track id
    "seen_box", never the sim's), and a user node with its tracked_state list and an action Client:
    (sim, perception, predictor, pusher, user, tracked, client)."""
    sim = SimNode(parameter_overrides=[Parameter("category", value="box"), Parameter("shape_seed", value=3),
                                       Parameter("publish_cloud_rate", value=15.0)])
    perception = PerceptionNode(parameter_overrides=[Parameter("object_id", value="seen_box")])  # not the sim's id
    perception_mode = Parameter("state_source", value="perception")
    predictor = PredictorNode(parameter_overrides=[perception_mode, Parameter("plan_max_topple_probability", value=0.6),
                                                   Parameter("plan_time_budget", value=plan_time_budget)])
    pusher = PusherNode(parameter_overrides=[perception_mode, Parameter("motion_timeout", value=motion_timeout)])
    user = rclpy_init.create_node(user_name)
    tracked: list[ObjectState] = []
    user.create_subscription(ObjectState, "tracked_state", tracked.append, STATE_QOS)
    return sim, perception, predictor, pusher, user, tracked, Client(user)


def test_push_to_goal_on_perception_alone(rclpy_init):
    sim, perception, predictor, pusher, user, tracked, client = box_on_camera(rclpy_init, "perception_user", 0.6, 3.0)
    for node, banned in ((predictor, {"object_state", "initial_twist", "observed_state"}), (pusher, {"object_state"})):
        topics = {s.topic_name.lstrip("/") for s in node.subscriptions}
        assert "tracked_state" in topics and not topics & banned, (node.get_name(), topics)
    with Spinner(sim, perception, predictor, pusher, user, threads=8):
        assert wait_for(lambda: tracked and predictor._features, 30), perception.last_error
        track = tracked[-1].object_id
        assert track == "seen_box" != sim.object_id
        x0, y0, _ = sim.spawn_pose
        goal = (x0 + 0.12, y0 + 0.03)
        result = client.send(goal_msg(*goal, object_id=track, position_tolerance=0.03, yaw_tolerance=math.pi,
                                      max_pushes=4), timeout=120.0)
        assert result.success and result.outcome == "reached", result.message
        pos, *_ = sim.sim.state(sim.object_id)  # the truth: the object rests within the tolerance (+ tracking)
        assert math.hypot(pos[0] - goal[0], pos[1] - goal[1]) < 0.035, (pos, goal)
        assert sim.push_id == result.pushes


def test_push_to_goal_ignores_the_yaw_of_an_upright_cylinder(rclpy_init):
    """A yaw goal half a turn from an upright cylinder's yaw, which no cloud can show: the pusher's stops fold the
    yaw as the planner does (the symmetry of the object's feature points) and the goal is reached by position."""
    sim = SimNode(parameter_overrides=[Parameter("category", value="cylinder"), Parameter("shape_seed", value=1),
                                       Parameter("publish_cloud_rate", value=5.0), Parameter("real_time_factor",
                                                                                             value=0.0)])
    perception = PerceptionNode()
    predictor = PredictorNode(parameter_overrides=[Parameter("plan_max_topple_probability", value=0.6),
                                                   Parameter("plan_time_budget", value=0.6)])
    pusher = PusherNode(parameter_overrides=[Parameter("motion_timeout", value=3.0)])
    user = rclpy_init.create_node("cylinder_user")
    states: list[ObjectState] = []
    user.create_subscription(ObjectState, "object_state", states.append, STATE_QOS)
    client = Client(user)
    with Spinner(sim, perception, predictor, pusher, user, threads=8):
        assert wait_for(lambda: states and predictor._features.get("object"), 30), perception.last_error
        x0, y0, yaw0 = sim.spawn_pose
        result = client.send(goal_msg(x0 + 0.1, y0, yaw0 + math.pi, position_tolerance=0.03,
                                      yaw_tolerance=math.radians(10.0), max_pushes=3), timeout=120.0)
        assert result.success and result.outcome == "reached", result.message
        assert result.yaw_error == 0.0  # the yaw is not checked: the cloud is symmetric about its up axis


def test_a_push_the_camera_sees_no_motion_of_does_not_end_the_goal(rclpy_init):
    """A push too weak to move the object visibly (here the goal's mass, a fiftieth of the box's, scales the
    planned impulse down; on a robot a mass read low from one side of the object does): the sim executes it, the
    camera sees the object resting where it was, and the session goes on from there instead of ending in a
    timeout."""
    sim, perception, predictor, pusher, user, tracked, client = box_on_camera(rclpy_init, "weak_push_user", 0.3, 1.5)
    with Spinner(sim, perception, predictor, pusher, user, threads=8):
        assert wait_for(lambda: tracked and predictor._features, 30), perception.last_error
        x0, y0, _ = sim.spawn_pose
        start, *_ = sim.sim.state(sim.object_id)
        mass = sim.sim.get(sim.object_id).mass
        result = client.send(goal_msg(x0 + 0.12, y0 + 0.03, object_id=tracked[-1].object_id,
                                      position_tolerance=0.03, yaw_tolerance=math.pi, max_pushes=2,
                                      mass=mass / 50.0), timeout=120.0)
        assert result.outcome != "timeout", result.message
        assert result.outcome == "out_of_pushes" and result.pushes == 2 == sim.push_id, result.message
        pos, *_ = sim.sim.state(sim.object_id)
        assert math.hypot(pos[0] - start[0], pos[1] - start[1]) < 0.01  # the pushes did not move it visibly
        assert pusher.counts["pushes"] == 2 == pusher.counts["pushes_unseen"]  # neither push was seen moving it


def test_a_push_with_no_state_of_the_object_after_it_times_out(rclpy_init):
    """The camera stops (its perception node deactivated) after the object was seen: the sim executes the push,
    no state of the object arrives, and the goal ends in a timeout that says so: a lost object is not taken for
    one that rests where it was."""
    sim, perception, predictor, pusher, user, tracked, client = box_on_camera(rclpy_init, "lost_object_user", 0.3, 1.5)
    with Spinner(sim, perception, predictor, pusher, user, threads=8):
        assert wait_for(lambda: tracked and predictor._features, 30), perception.last_error
        perception.trigger_deactivate()
        x0, y0, _ = sim.spawn_pose
        result = client.send(goal_msg(x0 + 0.12, y0 + 0.03, object_id=tracked[-1].object_id,
                                      position_tolerance=0.03, yaw_tolerance=math.pi, max_pushes=2), timeout=120.0)
        assert result.outcome == "timeout" and "nor seen resting" in result.message, result.message
        assert sim.push_id == 1 and pusher.counts["pushes_unseen"] == 0
