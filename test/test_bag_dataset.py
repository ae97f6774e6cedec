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
"""`physdyn bag2dataset` on a recorded sim session equals the dataset the simulator makes of the same pushes.

One session (module fixture): the sim node (pybullet, real_time_factor 0) and `physdyn record` run as
subprocesses; three objects are spawned and pushed through the node's services. The pushes are then simulated
again directly with the simulation core (what `physdyn generate` records) and compared frame by frame.
"""
from __future__ import annotations

import signal
import subprocess
import time

import numpy as np
import pytest

from conftest import PYTHON, ROOT
from physdyn_ros.cli import main as cli_main
from test_bag_support import Recorder, wait_until

#: (box shape seed, yaw, impulse direction * speed); the impulse is mass * this, at the centre of mass.
PUSHES = [(0, 0.0, (0.9, 0.0, 0.0)), (1, 0.3, (0.0, 1.2, 0.0)), (2, 0.6, (-0.9, 0.6, 0.0))]
TOPICS = ["object_state", "cloud", "initial_twist", "odom", "object_pose"]
#: States at rest recorded after each spawn and each push (bag2dataset's onset detection needs a few).
REST_STATES = 10


@pytest.fixture(scope="module")
def session(rclpy_init, tmp_path_factory):
    from geometry_msgs.msg import Vector3
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2

    from physdyn_ros.msg import ObjectState
    from physdyn_ros.ros.qos import CLOUD_QOS, STATE_QOS
    from physdyn_ros.ros.convert import time_to_ns
    from physdyn_ros.srv import PushObject, SpawnObject

    bag = tmp_path_factory.mktemp("session") / "bag"
    sim = subprocess.Popen([PYTHON, "-m", "physdyn_ros.nodes.sim_node", "--ros-args", "-p", "real_time_factor:=0.0",
                            "-p", "collision:=hull", "-p", "publish_cloud_rate:=5.0", "-p", "category:=box"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rec = None
    node = rclpy_init.create_node("bag_session_driver")
    # The driver watches what the recorder records, and waits for events instead of sleeping.
    states: list = []
    clouds: list = []
    receiving = [0]  # topics the recorder has recorded a message of (its /diagnostics)
    node.create_subscription(ObjectState, "object_state", states.append, STATE_QOS)
    node.create_subscription(PointCloud2, "cloud", clouds.append, CLOUD_QOS)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("recorder"):
                receiving[0] = int({kv.key: kv.value for kv in status.values}.get("topics_receiving", 0))

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)

    def spin_until(predicate, what: str, timeout: float = 30.0):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            rclpy_init.spin_once(node, timeout_sec=0.05)
        return predicate()

    try:
        rec = Recorder(bag, *TOPICS, "--split-duration", "2")
        push, spawn = node.create_client(PushObject, "push"), node.create_client(SpawnObject, "spawn_object")
        assert push.wait_for_service(timeout_sec=60) and spawn.wait_for_service(timeout_sec=10)
        # The recorder subscribes once it sees the sim's publishers; push only after it has.
        assert wait_until(lambda: all(any(i.node_name == "recorder" for i in node.get_subscriptions_info_by_topic(
            f"/{t}")) for t in TOPICS), timeout=30)
        # and the sim's writers have matched the recorder's readers: it records every topic the sim publishes
        # steadily (object_state, odom, object_pose, cloud; initial_twist's reader was announced with them)
        spin_until(lambda: receiving[0] >= len(TOPICS) - 1, "the recorder receiving the sim's topics")

        def call(client, request):
            future = client.call_async(request)
            rclpy_init.spin_until_future_complete(node, future, timeout_sec=30)
            assert future.done() and future.result().success, future.result()
            return future.result()

        masses = []
        for seed, yaw, v in PUSHES:
            masses.append(call(spawn, SpawnObject.Request(category="box", shape_seed=seed, yaw=yaw,
                                                          friction=0.5)).mass)
            # the new object's first state, then a cloud of it (5 Hz): the recorder gets them as the driver does
            n = len(states)
            t_spawn = time_to_ns(spin_until(lambda: states[n:] and states[n], "the new object's state").header.stamp)
            spin_until(lambda: any(time_to_ns(c.header.stamp) >= t_spawn for c in clouds), "its cloud")
            # and it rests for a few frames before the push: the respawn's jump is not taken for motion
            spin_until(lambda: len(states) - n >= REST_STATES, "states of the object at rest")
            m = masses[-1]
            n = len(states)
            call(push, PushObject.Request(impulse=Vector3(x=m * v[0], y=m * v[1], z=m * v[2])))
            # real_time_factor 0: the push is simulated within milliseconds; then the sim publishes the object at
            # rest (15 Hz). Enough rest frames must be recorded to tell this push from the next (bag2dataset).
            spin_until(lambda: sum(s.twist.linear.x == s.twist.linear.y == s.twist.angular.z == 0.0
                                   and s.twist.linear.z == s.twist.angular.x == s.twist.angular.y == 0.0
                                   for s in states[n + 1:]) >= REST_STATES, "the object at rest after the push")
        rc, out, err = rec.stop(signal.SIGINT)
        assert rc == 0, err
    finally:
        if rec is not None and rec.proc.poll() is None:
            rec.kill()
        sim.send_signal(signal.SIGINT)
        try:
            sim.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.communicate()
        node.destroy_node()
    return bag, masses


def _direct(masses: list[float], num_frames: int = 76) -> list[dict]:
    """The same pushes simulated directly (as `physdyn generate` records them)."""
    from physdyn_ros.shapes import make_procedural
    from physdyn_ros.sim import SimConfig, Simulator
    from physdyn_ros.sim.push import record

    out = []
    with Simulator(SimConfig(collision="hull")) as sim:
        for (seed, yaw, v), mass in zip(PUSHES, masses):
            shape = make_procedural("box", seed)
            sim.spawn(shape, xy=(0.0, 0.0), yaw=yaw, friction=0.5)
            assert abs(sim.mass - mass) < 1e-9
            sim.apply_impulse(sim.mass * np.asarray(v), sim.state()[0])
            out.append({**record(sim, num_frames), "points": shape.points})
    return out


def test_sim_session_equals_direct_simulation(session, tmp_path):
    from physdyn_ros.data import Dataset
    from physdyn_ros.learn.windows import load_sims

    bag, masses = session
    assert cli_main(["bag2dataset", str(bag), str(tmp_path / "ds"), "--friction", "0.5"]) == 0
    ds = Dataset(tmp_path / "ds")
    arrays = ds.load()
    assert len(arrays["pos"]) == 3 and ds.num_frames == 76
    for i, ref in enumerate(_direct(masses)):
        for key in ("pos", "quat", "lin_vel", "ang_vel"):
            np.testing.assert_allclose(arrays[key][i], ref[key], atol=2e-5, err_msg=f"push {i} {key}")
        assert arrays["length"][i] == ref["length"] and arrays["topple_index"][i] == ref["topple_index"]
        np.testing.assert_array_equal(arrays["toppled"][i], ref["toppled"])
        # The cloud, moved into the object frame, is the shape's own surface sample (the sim node publishes it).
        np.testing.assert_allclose(ds.points[arrays["shape_index"][i]] * arrays["scale"][i], ref["points"],
                                   atol=1e-5)
    assert arrays["friction"].tolist() == [0.5] * 3 and np.isnan(arrays["mass"]).all()
    assert sorted(sum(ds.splits.values(), [])) == sorted(s["id"] for s in ds.shapes)
    sims = load_sims(tmp_path / "ds", ["train", "val", "test"])  # what `physdyn train` reads
    assert len(sims) == 3


def test_tracker_sources(session, tmp_path):
    """A tracker instead of the sim's ObjectState: Odometry (twist in the object's axes) gives the same data;
    PoseStamped without initial_twist finds the pushes by motion onset and differentiates the poses."""
    from physdyn_ros.data import Dataset

    bag, _ = session
    assert cli_main(["bag2dataset", str(bag), str(tmp_path / "ref")]) == 0
    assert cli_main(["bag2dataset", str(bag), str(tmp_path / "odom"), "--state-topic", "odom"]) == 0
    assert cli_main(["bag2dataset", str(bag), str(tmp_path / "pose"), "--state-topic", "object_pose",
                     "--twist-topic", ""]) == 0
    ref, odom, pose = (Dataset(tmp_path / k).load() for k in ("ref", "odom", "pose"))
    for key in ("pos", "quat", "lin_vel", "ang_vel", "length"):
        np.testing.assert_allclose(odom[key], ref[key], atol=1e-5, err_msg=key)
    assert len(pose["pos"]) == 3  # the respawns (pose jumps) are not taken for pushes
    for i in range(3):
        moved = np.linalg.norm(ref["pos"][i, -1, :2] - ref["pos"][i, 0, :2])
        # The onset is the push instant, so the path starts where the push did and ends at the same rest pose.
        assert np.linalg.norm(pose["pos"][i, -1] - ref["pos"][i, -1]) < 1e-3  # rest frame may differ by one
        assert np.linalg.norm(pose["pos"][i, 0] - ref["pos"][i, 0]) < 0.2 * moved + 1e-3
        assert abs(int(pose["length"][i]) - int(ref["length"][i])) <= 3


def test_refusals(session, tmp_path, capsys):
    bag, _ = session
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "x").write_text("x")
    assert cli_main(["bag2dataset", str(bag), str(busy)]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert cli_main(["bag2dataset", str(bag), str(tmp_path / "ds"), "--state-topic", "predicted_path"]) == 2
    assert "no topic 'predicted_path'" in capsys.readouterr().err
    assert cli_main(["bag2dataset", str(tmp_path / "nope"), str(tmp_path / "ds")]) == 2
    assert not (tmp_path / "ds").exists()


def test_report_of_the_session(session, tmp_path, capsys):
    """`physdyn report` on a real session: one entry per push, the PNG written atomically, the JSON."""
    import json

    bag, _ = session
    png, out = tmp_path / "r.png", tmp_path / "r.json"
    assert cli_main(["report", str(bag), "--png", str(png), "--json", str(out)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left behind
    report = json.loads(out.read_text())
    assert len(report["pushes"]) == len(PUSHES)
