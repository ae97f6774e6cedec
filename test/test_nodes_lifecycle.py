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
"""Perception, predictor and sim are managed (lifecycle) nodes. Each is driven over DDS through its
lifecycle services (lifecycle_msgs/srv/ChangeState, GetState) through configure, activate, deactivate and cleanup:
it serves only while active (a request otherwise answers with the lifecycle state), /diagnostics reports the
state, the model (the simulator) is loaded on configure and released on cleanup, and a configure with a bad model
path fails cleanly: the node stays unconfigured, alive, with the reason, and configures once the path is fixed."""
from __future__ import annotations

import time
import uuid

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from physdyn_ros.msg import ObjectState, ShapeFeature
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.ros.qos import FEATURE_QOS
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.ros.qos import STATE_QOS
from physdyn_ros.ros.cloud import xyz_to_cloud
from physdyn_ros.ros.convert import vector3
from physdyn_ros.srv import PredictTrajectory, PushObject
from test_nodes_support import Spinner, call, tiny_model, wait_for  # noqa: F401 - fixture

RNG = np.random.default_rng(11)
#: a 10 x 6 x 8 cm box standing at (0.2, 0.1) on the table, as points in the table frame
BOX = (RNG.uniform(-1, 1, (800, 3)) * (0.05, 0.03, 0.04) + (0.2, 0.1, 0.04)).astype(np.float32)
INACTIVE = "node is inactive (lifecycle state 'inactive')"
#: s to wait for DDS under load
SLOW = 30.0


class Manager:
    """What `ros2 lifecycle` and a lifecycle manager do, from another node over DDS: change and get the state of
    one node; also records its /diagnostics."""

    def __init__(self, rclpy, target: str) -> None:
        self.target = target
        self.node = rclpy.create_node(f"manager_{uuid.uuid4().hex[:8]}")
        self.change = self.node.create_client(ChangeState, f"/{target}/change_state")
        self.get = self.node.create_client(GetState, f"/{target}/get_state")
        self.diagnostics: list[dict[str, str]] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id == f"/{self.target}":
                values = {kv.key: kv.value for kv in status.values}
                self.diagnostics.append(dict(values, level=int.from_bytes(status.level, "little"),
                                             message=status.message))

    def transition(self, transition_id: int) -> bool:
        return call(self.change, ChangeState.Request(transition=Transition(id=transition_id)), SLOW).success

    def configure(self) -> bool:
        return self.transition(Transition.TRANSITION_CONFIGURE)

    def activate(self) -> bool:
        return self.transition(Transition.TRANSITION_ACTIVATE)

    def deactivate(self) -> bool:
        return self.transition(Transition.TRANSITION_DEACTIVATE)

    def cleanup(self) -> bool:
        return self.transition(Transition.TRANSITION_CLEANUP)

    def state(self) -> str:
        return call(self.get, GetState.Request(), SLOW).current_state.label

    def diagnosed(self, **expected) -> dict[str, str]:
        """The first /diagnostics status of the node from now on whose values include `expected`."""
        start = len(self.diagnostics)

        def match():
            return next((d for d in self.diagnostics[start:]
                         if all(d.get(k) == str(v) for k, v in expected.items())), None)

        assert wait_for(match, SLOW), f"no /diagnostics with {expected}; last: {self.diagnostics[-1:]}"
        return match()


def service_gone(client, timeout: float = SLOW) -> bool:
    return wait_for(lambda: not client.service_is_ready(), timeout, 0.1)


def predict_request() -> PredictTrajectory.Request:
    req = PredictTrajectory.Request(horizon=10)
    req.header.frame_id = "world"
    req.cloud = xyz_to_cloud(BOX, "world")
    req.initial_pose.position.x, req.initial_pose.position.y, req.initial_pose.position.z = 0.2, 0.1, 0.04
    req.initial_twist.linear = vector3((0.4, 0.0, 0.0))
    return req


def test_predictor_configure_activate_deactivate_cleanup(rclpy_init, tiny_model):
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model)),
                                              Parameter("autostart", value=False)])
    m = Manager(rclpy_init, "predictor")
    predict = m.node.create_client(PredictTrajectory, "predict_trajectory")
    with Spinner(node, m.node):
        # unconfigured: parameters are there (declared in __init__), the model and the services are not
        assert m.state() == "unconfigured" and node.predictor is None
        assert node.get_parameter("horizon").value == 60
        d = m.diagnosed(lifecycle_state="unconfigured")
        assert d["model_id"] == "" and d["model_loaded"] == "False" and d["level"] == 1, d
        assert not predict.wait_for_service(timeout_sec=1.0)

        assert m.configure() and m.state() == "inactive"
        assert node.predictor is not None and node.model_id.startswith("tiny-test-")
        d = m.diagnosed(lifecycle_state="inactive", model_id=node.model_id)
        assert "not serving" in d["message"]
        res = call(predict, predict_request(), SLOW)  # the service exists but refuses: not active
        assert not res.success and INACTIVE in res.message, res.message

        assert m.activate() and m.state() == "active"
        res = call(predict, predict_request(), SLOW)
        assert res.success and len(res.trajectory.states) == 11 and res.trajectory.model_id == node.model_id
        m.diagnosed(lifecycle_state="active", model_id=node.model_id, predictions=1)

        assert m.deactivate() and m.state() == "inactive"
        res = call(predict, predict_request(), SLOW)
        assert not res.success and INACTIVE in res.message, res.message
        assert node.refused_inactive == 2 and node.predictions == 1  # refusals while inactive are not predictions

        # cleanup releases the model: it is gone from the node and from /diagnostics, and so are the services
        assert m.cleanup() and m.state() == "unconfigured"
        assert node.predictor is None and node.planner is None and node.model_id == ""
        m.diagnosed(lifecycle_state="unconfigured", model_id="", model_loaded=False)
        assert service_gone(predict), "predict_trajectory still offered after cleanup"
        # and the cycle can start again
        assert m.configure() and m.activate() and m.state() == "active"
        assert call(predict, predict_request(), SLOW).success


def test_predictor_configure_fails_cleanly_on_a_bad_model_path(rclpy_init, tiny_model, tmp_path):
    missing = tmp_path / "missing.pt"
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(missing)),
                                              Parameter("autostart", value=False)])
    m = Manager(rclpy_init, "predictor")
    with Spinner(node, m.node):
        assert not m.configure()  # FAILURE, not an error: back to unconfigured
        assert m.state() == "unconfigured"  # and alive: it still answers
        assert node.predictor is None and "cannot load model from" in node.transition_error
        d = m.diagnosed(lifecycle_state="unconfigured")
        assert str(missing) in d["transition_error"] and "cannot load model" in d["message"], d
        assert not m.activate() and m.state() == "unconfigured"  # no activate from unconfigured
        # the path is a parameter read on configure: fix it, configure again
        assert node.set_parameters([Parameter("model_path", value=str(tiny_model))])[0].successful
        assert m.configure() and m.activate() and m.state() == "active"
        assert node.transition_error == ""


def test_perception_processes_clouds_only_while_active(rclpy_init, tiny_model, tmp_path):
    node = PerceptionNode(parameter_overrides=[Parameter("model_path", value=str(tmp_path / "missing.pt")),
                                               Parameter("autostart", value=False)])
    m = Manager(rclpy_init, "perception")
    features: list[ShapeFeature] = []
    m.node.create_subscription(ShapeFeature, "shape_feature", features.append, FEATURE_QOS)
    clouds = m.node.create_publisher(PointCloud2, "cloud", 2)
    cloud = xyz_to_cloud(BOX, "world")

    def send_until(predicate, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            clouds.publish(cloud)  # best effort, depth 1: send again until it is seen
            if wait_for(predicate, 0.5):
                return True
        return bool(predicate())

    with Spinner(node, m.node):
        assert not m.configure() and m.state() == "unconfigured"
        assert "cannot load model from" in m.diagnosed(lifecycle_state="unconfigured")["transition_error"]
        node.set_parameters([Parameter("model_path", value=str(tiny_model))])
        assert m.configure() and m.state() == "inactive" and node.predictor is not None
        # inactive: no cloud subscription, nothing processed or published
        assert clouds.get_subscription_count() == 0
        for _ in range(5):
            clouds.publish(cloud)
            time.sleep(0.1)
        assert node.processed == 0 and not features

        assert m.activate() and m.state() == "active"
        assert send_until(lambda: features, SLOW), "no shape feature while active"
        assert features[-1].model_id == node.predictor.model_id
        m.diagnosed(lifecycle_state="active", model_loaded=True)

        assert m.deactivate() and m.state() == "inactive"
        assert wait_for(lambda: clouds.get_subscription_count() == 0, SLOW)
        processed = node.processed
        for _ in range(5):
            clouds.publish(cloud)
            time.sleep(0.1)
        assert node.processed == processed

        assert m.cleanup() and m.state() == "unconfigured"
        assert node.predictor is None
        m.diagnosed(lifecycle_state="unconfigured", model_id="", model_loaded=False)


def test_sim_simulates_and_pushes_only_while_active(rclpy_init, tmp_path):
    node = SimNode(parameter_overrides=[Parameter("real_time_factor", value=0.0),
                                        Parameter("publish_cloud_rate", value=0.0),
                                        Parameter("mesh_path", value=str(tmp_path / "missing.obj")),
                                        Parameter("autostart", value=False)])
    m = Manager(rclpy_init, "sim")
    states: list[ObjectState] = []
    m.node.create_subscription(ObjectState, "object_state", states.append, STATE_QOS)
    push = m.node.create_client(PushObject, "push")
    req = PushObject.Request(use_velocity=True)
    req.velocity.linear.x = 0.3

    with Spinner(node, m.node):
        assert m.state() == "unconfigured" and node.sim is None
        # a mesh that does not exist: configure fails, no simulator is left behind, the node stays alive
        assert not m.configure() and m.state() == "unconfigured" and node.sim is None
        assert "not found" in m.diagnosed(lifecycle_state="unconfigured")["transition_error"]
        node.set_parameters([Parameter("mesh_path", value="")])
        assert m.configure() and m.state() == "inactive" and node.sim is not None
        time.sleep(0.5)
        assert not states, "the sim published while inactive"
        res = call(push, req, SLOW)
        assert not res.success and INACTIVE in res.message, res.message

        assert m.activate() and m.state() == "active"
        assert wait_for(lambda: states, SLOW), "no object_state while active"
        res = call(push, req, SLOW)
        assert res.success, res.message
        m.diagnosed(lifecycle_state="active", simulator=True)

        assert m.deactivate() and m.state() == "inactive"
        assert not node._running  # a push in flight ends, the object is held still
        res = call(push, req, SLOW)
        assert not res.success and INACTIVE in res.message, res.message
        time.sleep(0.3)  # what was in flight
        count = len(states)
        time.sleep(0.5)
        assert len(states) == count, "the sim published while inactive"

        assert m.cleanup() and m.state() == "unconfigured"
        assert node.sim is None  # the pybullet client is closed
        m.diagnosed(lifecycle_state="unconfigured", simulator=False)
        assert service_gone(push), "push still offered after cleanup"


def test_up_without_autostart_leaves_the_nodes_to_a_lifecycle_manager(rclpy_init, tiny_model, tmp_path):
    """`physdyn up --no-autostart`: the nodes start unconfigured (what launch/physdyn.launch.py autostart:=false
    does); the launcher waits until each answers get_state; a manager then configures and activates them."""
    from physdyn_ros.launcher import Suite

    with Suite(overrides={"predictor": [f"model_path:={tiny_model}"]}, nodes=["predictor"],
               log_dir=tmp_path / "logs", autostart=False) as suite:
        assert suite.wait_ready(120)
        assert suite.states == {"predictor": "unconfigured"}
        m = Manager(rclpy_init, "predictor")
        predict = m.node.create_client(PredictTrajectory, "predict_trajectory")
        with Spinner(m.node):
            assert m.configure() and m.activate() and m.state() == "active"
            assert call(predict, predict_request(), SLOW).success
    log = (tmp_path / "logs" / "predictor.log").read_text()
    assert "autostart false" in log and "active: model tiny-test-" in log


def test_a_destroyed_or_failed_managed_node_leaves_the_graph(rclpy_init, tmp_path):
    """rclpy (Jazzy) keeps a LifecycleNode's rcl node alive through its state machine: destroyed nodes stayed in
    every process's graph (the demo then refused to start: "nodes ['sim', 'perception'] already run")."""
    import pytest

    from physdyn_ros.ros.model import ModelLoadError

    observer = rclpy_init.create_node(f"observer_{uuid.uuid4().hex[:8]}")
    try:
        def listed(name: str) -> bool:
            return name in observer.get_node_names()

        node = PredictorNode(parameter_overrides=[Parameter("autostart", value=False)])
        assert wait_for(lambda: listed("predictor"), SLOW)
        node.destroy_node()
        assert wait_for(lambda: not listed("predictor"), SLOW), "a destroyed managed node is still in the graph"
        # autostart with a model that cannot be loaded: the constructor raises and the node is gone too
        with pytest.raises(ModelLoadError, match="cannot load model from"):
            PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tmp_path / "missing.pt"))])
        time.sleep(1.0)
        assert not listed("predictor"), "a node whose autostart failed is still in the graph"
    finally:
        observer.destroy_node()


def test_an_action_server_accepts_goals_only_while_active(rclpy_init):
    """ManagedNode.configured_action_server (for action nodes such as the pusher): rejected unless active, gone
    after cleanup."""
    import pytest

    action = pytest.importorskip("physdyn_ros.action")
    from rclpy.action import ActionClient

    from physdyn_ros.ros.lifecycle import ManagedNode

    class Echo(ManagedNode):
        def __init__(self) -> None:
            super().__init__(f"echo_{uuid.uuid4().hex[:8]}", parameter_overrides=[Parameter("autostart", value=False)])
            self.start()

        def configure(self) -> None:
            self.configured_action_server(action.PushToGoal, "echo_goal", self.execute)

        def execute(self, goal_handle):
            goal_handle.succeed()
            return action.PushToGoal.Result(success=True, message="done")

    node = Echo()
    m = Manager(rclpy_init, node.get_name())
    client = ActionClient(m.node, action.PushToGoal, "echo_goal")

    def send():
        future = client.send_goal_async(action.PushToGoal.Goal())
        assert wait_for(future.done, SLOW), "no answer to the goal"
        return future.result()

    with Spinner(node, m.node):
        assert m.configure() and client.wait_for_server(timeout_sec=SLOW)
        assert not send().accepted and node.refused_inactive == 1  # inactive
        assert m.activate()
        handle = send()
        assert handle.accepted
        result = handle.get_result_async()
        assert wait_for(result.done, SLOW) and result.result().result.message == "done"
        assert m.deactivate() and not send().accepted
        assert m.cleanup()
        assert wait_for(lambda: not client.server_is_ready(), SLOW), "the action server outlived cleanup"
        client.destroy()
