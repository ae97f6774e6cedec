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
"""The generated interfaces work over the real middleware: across processes, on loopback DDS."""
from __future__ import annotations

import json
import subprocess
import textwrap
import time

import pytest

from conftest import PYTHON

SUBSCRIBER = textwrap.dedent("""
    import json, sys, rclpy
    from physdyn_ros.msg import PredictedTrajectory
    rclpy.init()
    node = rclpy.create_node('test_sub')
    got = []
    node.create_subscription(PredictedTrajectory, 'traj', got.append, 10)
    print('ready', flush=True)
    while not got:
        rclpy.spin_once(node, timeout_sec=0.1)
    m = got[0]
    print(json.dumps({
        'frame': m.header.frame_id, 'object_id': m.object_id, 'model_id': m.model_id,
        'dt_ns': m.time_step.nanosec, 'n': len(m.states),
        'x': [s.pose.position.x for s in m.states], 'toppled': [s.toppled for s in m.states],
        'p': m.topple_probability}), flush=True)
    node.destroy_node(); rclpy.shutdown()
""")

SERVER = textwrap.dedent("""
    import rclpy
    from physdyn_ros.srv import PredictTrajectory
    from physdyn_ros.msg import ObjectState
    def handle(req, res):
        res.success = req.horizon > 0
        res.message = 'echo ' + req.object_id
        res.trajectory.object_id = req.object_id
        res.trajectory.states = [ObjectState() for _ in range(req.horizon + 1)]
        res.topple_probability = float(req.initial_twist.linear.x)
        return res
    rclpy.init()
    node = rclpy.create_node('test_server')
    node.create_service(PredictTrajectory, 'predict', handle)
    print('ready', flush=True)
    rclpy.spin(node)
""")


def test_trajectory_crosses_processes(rclpy_init):
    from physdyn_ros.msg import ObjectState, PredictedTrajectory

    rclpy = rclpy_init
    sub = subprocess.Popen([PYTHON, "-c", SUBSCRIBER], stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout.readline().strip() == "ready"
        node = rclpy.create_node("test_pub")
        pub = node.create_publisher(PredictedTrajectory, "traj", 10)
        msg = PredictedTrajectory()
        msg.header.frame_id = "world"
        msg.object_id = "mug_3"
        msg.model_id = "test-model"
        msg.time_step.nanosec = 66_666_667
        msg.topple_probability = 0.25
        for k in range(61):
            s = ObjectState()
            s.pose.position.x = 0.01 * k
            s.toppled = k > 50
            msg.states.append(s)
        deadline = time.monotonic() + 30
        while sub.poll() is None and time.monotonic() < deadline:
            pub.publish(msg)
            rclpy.spin_once(node, timeout_sec=0.1)
        out, _ = sub.communicate(timeout=10)
        node.destroy_node()
    finally:
        sub.kill()
    got = json.loads(out.strip().splitlines()[-1])
    assert got["frame"] == "world" and got["object_id"] == "mug_3" and got["model_id"] == "test-model"
    assert got["dt_ns"] == 66_666_667 and got["n"] == 61
    assert got["x"] == pytest.approx([0.01 * k for k in range(61)])
    assert got["toppled"] == [k > 50 for k in range(61)]
    assert got["p"] == pytest.approx(0.25)


def test_service_is_answered_across_processes(rclpy_init):
    from physdyn_ros.srv import PredictTrajectory

    rclpy = rclpy_init
    server = subprocess.Popen([PYTHON, "-c", SERVER], stdout=subprocess.PIPE, text=True)
    try:
        assert server.stdout.readline().strip() == "ready"
        node = rclpy.create_node("test_client")
        client = node.create_client(PredictTrajectory, "predict")
        assert client.wait_for_service(timeout_sec=30), "service never appeared"
        req = PredictTrajectory.Request()
        req.object_id = "box_1"
        req.horizon = 60
        req.initial_twist.linear.x = 0.5
        future = client.call_async(req)
        rclpy.spin_until_future_complete(node, future, timeout_sec=30)
        res = future.result()
        node.destroy_node()
    finally:
        server.kill()
    assert res is not None, "no answer"
    assert res.success and res.message == "echo box_1"
    assert len(res.trajectory.states) == 61
    assert res.topple_probability == pytest.approx(0.5)
