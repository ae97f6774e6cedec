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
"""No input, parameter value, log sequence or signal makes a node exit or answer wrongly without a word."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointField

from conftest import PYTHON, ROOT
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.ros.cloud import xyz_to_cloud
from physdyn_ros.ros.qos import SERVICE_CLIENT_QOS
from physdyn_ros.srv import PlanPush, PredictTrajectory, PushObject, SpawnObject
from test_nodes_support import Spinner, call, tiny_model, wait_for  # noqa: F401 - fixture

RNG = np.random.default_rng(3)


def box_points(n: int = 600, centre=(0.2, 0.1, 0.04), half=(0.05, 0.03, 0.04)) -> np.ndarray:
    return (RNG.uniform(-1, 1, (n, 3)) * half + centre).astype(np.float32)


def set_params(node, **values) -> list:
    """node.set_parameters as SetParameters does it: one result per parameter, nothing raised."""
    return node.set_parameters([Parameter(k, value=v) for k, v in values.items()])


# ------------------------------------------------------------------------------------------------- logging
def test_throttles_of_two_severities_share_one_logger(rclpy_init):
    """rclpy binds one severity to a call site: a warning then an error through one site raised ValueError."""
    from physdyn_ros.ros.throttle import ReasonThrottle

    node = rclpy_init.create_node("throttle_probe")
    try:
        warn = ReasonThrottle(node.get_logger(), "warning", 1.0)
        error = ReasonThrottle(node.get_logger(), "error", 1.0)
        note = ReasonThrottle(node.get_logger(), "info", 1.0)
        assert warn("a warning", "w") and error("an error", "e") and note("a note", "n") and warn("another", "w2")
    finally:
        node.destroy_node()
    with pytest.raises(ValueError, match="severity"):
        ReasonThrottle(node.get_logger(), "loud")


def test_predictor_lives_through_a_refused_request_then_a_bad_twist(rclpy_init, tiny_model):
    """A refused predict_trajectory (a warning) then a twist in another frame (an error) killed the node."""
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    user = rclpy_init.create_node("robust_user")
    client = user.create_client(PredictTrajectory, "predict_trajectory", qos_profile=SERVICE_CLIENT_QOS)
    twists = user.create_publisher(TwistStamped, "initial_twist", 10)
    req = PredictTrajectory.Request()
    req.header.frame_id = "world"
    req.cloud = xyz_to_cloud(box_points(), "world")
    req.initial_pose.position.x, req.initial_pose.position.y, req.initial_pose.position.z = 0.2, 0.1, 0.04
    with Spinner(node, user):
        req.initial_twist.linear.x = 99.0
        res = call(client, req)
        assert not res.success and "max_linear_speed" in res.message
        bad = TwistStamped()
        bad.header.frame_id = "map"
        bad.header.stamp.sec = 5
        bad.twist.linear.x = 0.3
        assert wait_for(lambda: (twists.publish(bad), node.rejected >= 2)[1], 10, step=0.2), node.last_error
        assert "frame_id 'map'" in node.last_error
        req.initial_twist.linear.x = 0.3  # the node still answers
        res = call(client, req)
        assert res.success, res.message
    assert node.callback_errors == 0
    user.destroy_node()


def test_perception_lives_through_a_note_then_a_refused_cloud(rclpy_init, tiny_model):
    """The info note "2 objects in the cloud" then a warning for an empty cloud killed the node."""
    node = PerceptionNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    try:
        two = np.concatenate([box_points(800), box_points(800, centre=(-0.2, -0.1, 0.04))])
        node.on_cloud(xyz_to_cloud(two, "world"))  # single_object: a note that only one is published
        node.on_cloud(xyz_to_cloud(np.zeros((0, 3), np.float32), "world"))
        assert "empty" in node.last_error
        assert set_params(node, min_points=100_000)[0].successful
        node.on_cloud(xyz_to_cloud(two, "world"))  # every cluster too small now: another warning
        assert node.processed == 1
    finally:
        node.destroy_node()


def test_a_callback_that_raises_is_logged_and_the_node_goes_on(rclpy_init):
    """The suite's managed callbacks (subscriptions, timers, services) never let an exception reach the
    executor, which would end the node's spin; a service answers the failure with its reason."""
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from physdyn_ros.ros.lifecycle import ManagedNode

    class Faulty(ManagedNode):
        def __init__(self) -> None:
            super().__init__("faulty")
            self.seen = 0
            self.start()

        def configure(self) -> None:
            self.configured_service(Trigger, "faulty_trigger", self._boom_service)

        def activate(self) -> None:
            self.active_subscription(String, "faulty_topic", self._boom, 10)

        def _boom(self, msg) -> None:
            self.seen += 1
            raise RuntimeError(f"bug on {msg.data}")

        def _boom_service(self, req, res):
            raise KeyError("missing")

    node = Faulty()
    user = rclpy_init.create_node("faulty_user")
    pub = user.create_publisher(String, "faulty_topic", 10)
    client = user.create_client(Trigger, "faulty_trigger", qos_profile=SERVICE_CLIENT_QOS)
    with Spinner(node, user) as spinner:
        assert wait_for(lambda: (pub.publish(String(data="x")), node.seen >= 2)[1], 10, step=0.1)
        res = call(client, Trigger.Request())
        assert not res.success and "internal error: KeyError" in res.message
        assert spinner.thread.is_alive()
    assert node.callback_errors >= 3


def test_deactivating_from_another_thread_never_stops_the_spinning_thread(rclpy_init):
    """Deactivate destroys a node's subscriptions while another thread builds the executor's wait set: rclpy then
    raised InvalidHandle out of spin_once, the spinning thread ended and every later reply was lost (a lifecycle
    manager's deactivate, the pusher's tests). A tiny GIL switch interval makes the race frequent."""
    import sys

    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from physdyn_ros.ros.lifecycle import ManagedNode

    class Cycled(ManagedNode):
        def __init__(self) -> None:
            super().__init__("cycled")
            self.start()

        def configure(self) -> None:
            self.configured_service(Trigger, "cycled_trigger", lambda req, res: setattr(res, "success", True) or res)

        def activate(self) -> None:
            for topic in ("cycled_a", "cycled_b", "cycled_c"):
                self.active_subscription(String, topic, lambda msg: None, 10)

    node = Cycled()
    user = rclpy_init.create_node("cycled_user")
    client = user.create_client(Trigger, "cycled_trigger", qos_profile=SERVICE_CLIENT_QOS)
    interval = sys.getswitchinterval()
    with Spinner(node, user, threads=4) as spinner:
        sys.setswitchinterval(1e-6)
        try:
            cycles, t_end = 0, time.monotonic() + 6.0
            while time.monotonic() < t_end and spinner.thread.is_alive():
                node.trigger_deactivate()
                node.trigger_activate()
                cycles += 1
        finally:
            sys.setswitchinterval(interval)
        assert spinner.thread.is_alive(), f"the spinning thread ended after {cycles} deactivations"
        assert node.is_active and call(client, Trigger.Request()).success


# ---------------------------------------------------------------------------------------------- parameters
def test_sim_camera_parameters_are_checked_when_set(rclpy_init):
    node = SimNode(parameter_overrides=[Parameter("cloud_source", value="camera"),
                                        Parameter("publish_cloud_rate", value=0.0)])
    try:
        for name, value, why in [("camera_resolution", [0, 0], "every value in"),
                                 ("camera_resolution", [320], "needs 2 values"),
                                 ("camera_eye", [0.6, 0.0], "needs 3 values"),
                                 ("camera_eye", [0.0, 0.0, 0.05], "must differ from camera_target"),
                                 ("cloud_source", "bogus", "must be one of surface, camera"),
                                 ("scale", [1.0, 0.0, 1.0], "every value in"),
                                 ("spawn_pose", [1e9, 0.0, 0.0], "every value in")]:
            before = node.get_parameter(name).value
            result = set_params(node, **{name: value})[0]
            assert not result.successful and name in result.reason and why in result.reason, (name, result.reason)
            assert list(node.get_parameter(name).value) == list(before) if isinstance(before, list) else \
                node.get_parameter(name).value == before
        assert len(node.current_cloud()) > 50  # the camera still renders with the unchanged parameters
        node._on_cloud()
    finally:
        node.destroy_node()


def test_sim_refuses_a_bad_camera_at_start(rclpy_init):
    with pytest.raises(Exception, match="camera_resolution"):
        SimNode(parameter_overrides=[Parameter("camera_resolution", value=[0, 240])])


def test_predictor_parameters_are_checked_when_set(rclpy_init, tiny_model):
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    try:
        max_h = int(node.predictor.max_horizon)
        for name, value, why in [("horizon", max_h + 1, f"exceeds the max_horizon {max_h}"),
                                 ("plan_table_bounds", [1.0], "needs 4 values"),
                                 ("plan_table_bounds", [1.0, -1.0, -1.0, 1.0], "x_min < x_max"),
                                 ("initial_pose_source", "imu", "must be one of")]:
            result = set_params(node, **{name: value})[0]
            assert not result.successful and why in result.reason, (name, result.reason)
        assert node.get_parameter("horizon").value == 60
        assert list(node.get_parameter("plan_table_bounds").value) == [-1.0, 1.0, -1.0, 1.0]
        assert set_params(node, horizon=max_h)[0].successful
    finally:
        node.destroy_node()


def test_perception_parameters_are_checked_when_set(rclpy_init, tiny_model):
    node = PerceptionNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    try:
        for name, value, why in [("crop_min", [0.0], "needs 3 values"),
                                 ("crop_max", [9.0, 9.0, -5.0], "above crop_min"),
                                 ("sensor_transform", [0.0] * 7, "zero quaternion")]:
            result = set_params(node, **{name: value})[0]
            assert not result.successful and why in result.reason, (name, result.reason)
        node.on_cloud(xyz_to_cloud(box_points(800), "world"))
        assert node.processed == 1, node.last_error
    finally:
        node.destroy_node()


@pytest.mark.parametrize("value, why", [("abc", "expects an integer, got 'abc'"),
                                        ("2.5", "expects an integer, got 2.5")])
def test_physdyn_up_refuses_a_parameter_of_the_wrong_type(value, why):
    """`--param predictor:horizon:=abc` is refused with the reason, never ignored in silence (rcl keeps the first
    params file's type)."""
    run = subprocess.run([str(ROOT / ".venv" / "bin" / "physdyn"), "up", "--nodes", "predictor", "--param",
                          f"predictor:horizon:={value}"], capture_output=True, text=True, timeout=60)
    assert run.returncode != 0
    assert why in run.stderr and "horizon" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr and "remap rule" not in run.stdout + run.stderr


def test_a_params_file_of_the_wrong_length_stops_the_node_with_the_name(tmp_path, tiny_model):
    params = tmp_path / "p.yaml"
    params.write_text("/**/perception:\n  ros__parameters:\n    crop_min: [0.0]\n")
    run = subprocess.run([PYTHON, "-m", "physdyn_ros.nodes.perception_node", "--ros-args", "-p",
                          f"model_path:={tiny_model}", "--params-file", str(params)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "cannot start" in run.stderr + run.stdout and "crop_min needs 3 values" in run.stderr + run.stdout


# ------------------------------------------------------------------------------------------------- inputs
def test_predictor_refuses_vertical_launches(rclpy_init, tiny_model):
    """linear.z = +3 ended floating 8 cm above the table, -4 inside it: outside the trained pushes."""
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    try:
        for vz in (3.0, -4.0):
            req = PredictTrajectory.Request()
            req.header.frame_id = "world"
            req.cloud = xyz_to_cloud(box_points(), "world")
            req.initial_pose.position.x, req.initial_pose.position.y, req.initial_pose.position.z = 0.2, 0.1, 0.04
            req.initial_twist.linear.x, req.initial_twist.linear.z = 0.3, vz
            res = node._on_service(req, PredictTrajectory.Response())
            assert not res.success and "max_vertical_speed" in res.message, res.message
        req.initial_twist.linear.z = 0.2
        assert node._on_service(req, PredictTrajectory.Response()).success
    finally:
        node.destroy_node()


def test_plan_push_names_a_tolerance_below_what_a_push_can_reach(rclpy_init, tiny_model):
    node = PredictorNode(parameter_overrides=[Parameter("model_path", value=str(tiny_model))])
    try:
        req = PlanPush.Request(position_tolerance=1e-12)
        req.header.frame_id = "world"
        req.cloud = xyz_to_cloud(box_points(), "world")
        req.start_pose.position.x, req.start_pose.position.y = 0.2, 0.1
        req.goal_pose.position.x, req.goal_pose.position.y = 0.3, 0.1
        res = node._on_plan(req, PlanPush.Response())
        assert not res.success and "position_tolerance 1e-12 m is below" in res.message, res.message
    finally:
        node.destroy_node()


def test_a_cloud_with_a_repeated_coordinate_field_is_refused():
    from physdyn_ros.ros.cloud import cloud_to_xyz

    msg = xyz_to_cloud(box_points(10), "world")
    msg.fields = list(msg.fields) + [PointField(name="x", offset=0, datatype=PointField.FLOAT32, count=1)]
    with pytest.raises(ValueError, match="field x more than once"):
        cloud_to_xyz(msg)


def test_sim_refuses_far_contacts_absurd_spawns_and_zero_velocities(rclpy_init):
    node = SimNode(parameter_overrides=[Parameter("publish_cloud_rate", value=0.0), Parameter("category", value="box")])
    try:
        pos = node.sim.state(node.object_id)[0]
        half = node.half_extents()
        req = PushObject.Request()
        req.impulse.x = 0.05
        req.point.x, req.point.y, req.point.z = pos[0] - half[0] - 0.9, pos[1], pos[2]
        res = node._on_push(req, PushObject.Response())
        assert not res.success and "outside the surface" in res.message, res.message
        req.point.x = float(pos[0] - half[0] - 0.005)  # just off the face: a pusher's tip
        assert node._on_push(req, PushObject.Response()).success
        node.reset()
        zero = PushObject.Request(use_velocity=True)
        res = node._on_push(zero, PushObject.Response())
        assert not res.success and "velocity is zero" in res.message, res.message
        far = SpawnObject.Request(object_id="far", category="box", x=1e9)
        res = node._on_spawn(far, SpawnObject.Response())
        assert not res.success and "more than 10 m" in res.message, res.message
        assert "far" not in node.objects
    finally:
        node.destroy_node()


def test_an_unavailable_device_is_named_not_blamed_on_the_checkpoint():
    from physdyn_ros.ros.model import ModelLoadError, check_device

    for device, why in [("cuda:7", "CUDA device"), ("tpu", "not a torch device"), ("meta", "only cpu and cuda")]:
        with pytest.raises(ModelLoadError, match=why):
            check_device(device)
    check_device("cpu")


def test_the_suite_clients_keep_every_reply(rclpy_init):
    """The pusher's clients (and reliable_client) keep all replies: rclpy's default keeps the last 10."""
    from rclpy.qos import HistoryPolicy

    from physdyn_ros.nodes.pusher_node import PusherNode

    node = PusherNode()
    try:
        for client in (node.plan_client, node.predict_client, node.push_client):
            assert client.qos_profile.history == HistoryPolicy.KEEP_ALL
    finally:
        node.destroy_node()


# ------------------------------------------------------------------------------------------------ signals
def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP])
def test_physdyn_up_leaves_no_node_behind(tiny_model, tmp_path, sig):
    """Killed physdyn up (SIGKILL included) left its nodes running under PID 1; a second one then joined them."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [str(ROOT / ".venv" / "bin" / "physdyn"), "up", "--nodes", "predictor", "--model", str(tiny_model)]
    up = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        lines = []
        for line in up.stdout:
            lines.append(line)
            if "all nodes ready" in line:
                break
        assert any("all nodes ready" in ln for ln in lines), "".join(lines[-20:])
        nodes = _children(up.pid)
        assert nodes, "no node process found"
        second = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env)
        assert second.returncode == 1 and "already run" in second.stderr, second.stdout + second.stderr
        up.send_signal(sig)
        up.wait(30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(p) for p in nodes):
            time.sleep(0.2)
        assert not any(_alive(p) for p in nodes), f"node processes {nodes} outlived physdyn up ({sig!r})"
    finally:
        if up.poll() is None:
            up.kill()
        for p in _children(up.pid):
            os.kill(p, signal.SIGKILL)


def test_a_node_stops_when_its_parent_is_gone(tiny_model):
    """A node started with PHYSDYN_PARENT_PID of a process that is not its parent refuses to start."""
    env = dict(os.environ, PHYSDYN_PARENT_PID="1")
    run = subprocess.run([PYTHON, "-m", "physdyn_ros.nodes.predictor_node", "--ros-args", "-p",
                          f"model_path:={tiny_model}"], capture_output=True, text=True, timeout=60, env=env)
    assert run.returncode == 1 and "is gone" in run.stdout + run.stderr
