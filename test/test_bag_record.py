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
"""`physdyn record` over real DDS: byte-exact bags, clean stops during bursts, kill -9, refusals, size limit.

Publishers live in the test process and publish raw CDR bytes (rosbags-serialized, zero padding), so what
DDS delivers, and what the bag must hold, is exactly those bytes. (DDS pads a payload to a multiple of 4 bytes;
the test messages are sized so that it does not have to.) The recorder runs as a subprocess.
"""
from __future__ import annotations

import signal
import subprocess
import time

import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader

from conftest import PYTHON, ROOT
from physdyn_ros.bag.types import typestore
from physdyn_ros.bag.writer import BagWriter
from test_bag_support import OBJECT_STATE, Recorder, object_state_bytes, read_bag, string_bytes, wait_until

BURST = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _publishers(node, *topics):
    from physdyn_ros.msg import ObjectState
    from std_msgs.msg import String

    return [node.create_publisher(ObjectState if t == "object_state" else String, t, q) for t, q in topics]


@pytest.mark.parametrize("sig,storage", [(signal.SIGINT, "mcap"), (signal.SIGTERM, "sqlite3")])
def test_clean_stop_during_burst_loses_nothing(rclpy_init, tmp_path, sig, storage):
    node = rclpy_init.create_node(f"bag_pub_{storage}")
    latched, = _publishers(node, ("latched", LATCHED))
    latched.publish(string_bytes("before the recorder"))
    rec = Recorder(tmp_path / "bag", "object_state", "/chatter:std_msgs/msg/String", "latched:std_msgs/String",
                   "--storage", storage, "--split-duration", "0.3")
    try:
        states, chatter = _publishers(node, ("object_state", BURST), ("chatter", 10))
        assert wait_until(lambda: states.get_subscription_count() and chatter.get_subscription_count()
                          and latched.get_subscription_count())
        assert all(len(string_bytes(t)) % 4 == 0 for t in ("before the recorder", "chat000"))
        sent = []
        t_start = time.time_ns()
        for i in range(2000):  # as fast as Python publishes, then stop at once
            data = object_state_bytes(i)
            states.publish(data)
            sent.append(data)
            if i % 100 == 0:
                chatter.publish(string_bytes(f"chat{i // 100:03d}"))
        rc, out, err = rec.stop(sig)
        t_end = time.time_ns()
    finally:
        if rec.proc.poll() is None:
            rec.kill()
    assert rc == 0, err[-2000:]
    assert "2021 messages on 3 topic(s)" in out, out
    got = read_bag(tmp_path / "bag")
    assert [d for t, _, d in got if t == "/object_state"] == sent  # all of them, in order, byte for byte
    chat = [string_bytes(f"chat{i // 100:03d}") for i in range(0, 2000, 100)]
    assert [d for t, _, d in got if t == "/chatter"] == chat
    assert [d for t, _, d in got if t == "/latched"] == [string_bytes("before the recorder")]
    assert all(t_start <= t <= t_end for topic, t, _ in got if topic != "/latched")  # receive times
    with Reader(tmp_path / "bag") as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns["/object_state"].msgtype == OBJECT_STATE
        # The recorded type hash is the one rosidl generated for the publisher's type.
        info = node.get_publishers_info_by_topic("/object_state")[0]
        assert conns["/object_state"].digest == "RIHS01_" + info.topic_type_hash.value.hex()
        assert conns["/object_state"].digest == typestore().hash_rihs01(OBJECT_STATE)
        qos = conns["/latched"].ext.offered_qos_profiles[0]
        assert qos.durability == QosDurability.TRANSIENT_LOCAL and qos.reliability == QosReliability.RELIABLE
    node.destroy_node()


def test_killed_recorder_leaves_a_readable_bag(rclpy_init, tmp_path):
    """kill -9: everything older than one file (0.5 s here) plus one poll period is in the bag, in order."""
    node = rclpy_init.create_node("bag_pub_kill")
    states, = _publishers(node, ("object_state", BURST))
    rec = Recorder(tmp_path / "bag", "object_state", "--split-duration", "0.5")
    try:
        assert wait_until(lambda: states.get_subscription_count() > 0)
        sent, times = [], []
        t0 = time.monotonic()
        i = 0
        while time.monotonic() - t0 < 2.5:
            data = object_state_bytes(i)
            states.publish(data)
            sent.append(data)
            times.append(time.monotonic())
            i += 1
            time.sleep(0.02)
        rec.proc.kill()
        t_kill = time.monotonic()
        rec.proc.communicate(timeout=20)
    finally:
        if rec.proc.poll() is None:
            rec.kill()
    got = [d for _, _, d in read_bag(tmp_path / "bag")]
    bound = 0.5 + 0.5  # --split-duration + poll period and scheduling slack
    must_have = sum(1 for t in times if t <= t_kill - bound)
    assert must_have > 50
    assert len(got) >= must_have and got == sent[:len(got)]
    node.destroy_node()


def test_refusals_are_one_line_errors(tmp_path):
    existing = BagWriter(tmp_path / "old")
    existing.open()
    existing.close()
    procs = {
        "exists": [PYTHON, "-m", "physdyn_ros.cli", "record", "-o", str(tmp_path / "old"), "object_state"],
        "type": [PYTHON, "-m", "physdyn_ros.cli", "record", "-o", str(tmp_path / "new"), "/x:foo_msgs/msg/Bar"],
        "name": [PYTHON, "-m", "physdyn_ros.cli", "record", "-o", str(tmp_path / "new2"), "bad topic!"],
    }
    runs = {k: subprocess.Popen(v, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for k, v in procs.items()}
    res = {k: (p.wait(timeout=60), p.communicate()[1]) for k, p in runs.items()}
    assert res["exists"][0] == 2 and "already holds a bag" in res["exists"][1], res["exists"]
    assert res["type"][0] == 2 and "unknown message type 'foo_msgs/msg/Bar'" in res["type"][1], res["type"]
    assert res["name"][0] == 2 and "bad topic name" in res["name"][1], res["name"]
    for k, (_, err) in res.items():
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "new").exists() and not (tmp_path / "new2").exists()


def test_max_bytes_stops_the_recorder_cleanly(rclpy_init, tmp_path):
    node = rclpy_init.create_node("bag_pub_full")
    states, = _publishers(node, ("object_state", BURST))
    rec = Recorder(tmp_path / "bag", "object_state", "--max-bytes", "700k", "--split-size", "100k")
    try:
        assert wait_until(lambda: states.get_subscription_count() > 0)
        sent = []
        i = 0
        while rec.proc.poll() is None and i < 200_000:
            data = object_state_bytes(i)
            states.publish(data)
            sent.append(data)
            i += 1
            if i % 200 == 0:
                time.sleep(0.01)
        out, err = rec.proc.communicate(timeout=20)
    finally:
        if rec.proc.poll() is None:
            rec.kill()
    assert rec.proc.returncode == 2 and "size limit reached" in err, err[-2000:]
    got = [d for _, _, d in read_bag(tmp_path / "bag")]
    assert len(got) > 1000 and got == sent[:len(got)]
    assert sum(p.stat().st_size for p in (tmp_path / "bag").iterdir()) <= 700 * 1024
    node.destroy_node()


def test_recorder_publishes_diagnostics(rclpy_init, tmp_path):
    """The recorder reports on /diagnostics what it records and receives."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    node = rclpy_init.create_node("bag_pub_diag")
    states, = _publishers(node, ("object_state", BURST))
    got: list = []
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: got.extend(s for s in m.status if s.name == "recorder: recording"), 10)
    rec = Recorder(tmp_path / "bag", "object_state")
    try:
        assert wait_until(lambda: states.get_subscription_count() > 0)
        for i in range(20):
            states.publish(object_state_bytes(i))

        def received() -> bool:
            rclpy_init.spin_once(node, timeout_sec=0.1)
            return any({kv.key: kv.value for kv in s.values}.get("received") == "20" for s in got)
        assert wait_until(received, timeout=15), [[(kv.key, kv.value) for kv in s.values] for s in got[-1:]]
        rc, _, err = rec.stop(signal.SIGINT)
        assert rc == 0, err
    finally:
        if rec.proc.poll() is None:
            rec.kill()
        node.destroy_node()
    last = got[-1]
    values = {kv.key: kv.value for kv in last.values}
    assert last.level == DiagnosticStatus.OK and values["topics_recording"] == "1" and values["lost"] == "0"
