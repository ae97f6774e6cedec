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
"""kill -9 of recorder_node over real DDS: the unfinished split holds every complete chunk, readable without footer.

The recorder node runs as its own process (`python -m physdyn_ros.nodes.recorder_node --ros-args ...`) with a
split duration far beyond the test, so everything it records goes to one unfinished split. The test publishes
large messages (more than rosbags' 1 MiB chunk size: a chunk completed by size) and then small ones at 50 Hz
(chunks completed by age, CHUNK_PERIOD), waits until all of it is in complete chunks on disk (at most the
bound), publishes a few more and kills the node with SIGKILL. The unfinished file is then read record by record
from its start, as `mcap recover` does (test_bag_support.scan_mcap, a parser independent of the writer):
everything published before the wait must be there, byte for byte and in order, in complete, indexed chunks.
"""
from __future__ import annotations

import os
import subprocess
import time

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from conftest import PYTHON, ROOT
from physdyn_ros.bag.writer import CHUNK_PERIOD
from test_bag_support import object_state_bytes, read_bag, scan_mcap, string_bytes, wait_until

RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
TICK = 0.1  # the recorder's discovery / tick period
BIG = 8191  # characters per large String: 8200 bytes of CDR, a multiple of 4 (no DDS padding)


def _start_recorder(out, timeout: float = 60.0) -> subprocess.Popen:
    proc = subprocess.Popen(
        [PYTHON, "-m", "physdyn_ros.nodes.recorder_node", "--ros-args", "-p", f"output:={out}",
         "-p", "topics:=['object_state', '/chatter:std_msgs/msg/String']", "-p", "split_duration:=600.0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("recording "):
            return proc
        if not line and proc.poll() is not None:
            raise RuntimeError(f"recorder exited ({proc.returncode}): {proc.stderr.read()[-2000:]}")
    proc.kill()
    proc.communicate(timeout=20)
    raise TimeoutError("recorder did not start")


class _Counts(dict):
    """Messages per topic; `>=` another: at least as many on every topic of the other."""

    def __ge__(self, other):
        return all(self.get(t, 0) >= n for t, n in other.items())


def _on_disk(path) -> _Counts:
    """Messages per topic in the complete chunks of an MCAP file being written (none before it exists)."""
    counts = _Counts()
    if path.is_file() and path.stat().st_size >= 8:
        for topic, _, _ in scan_mcap(path)["messages"]:
            counts[topic] = counts.get(topic, 0) + 1
    return counts


def test_killed_recorder_node_leaves_its_complete_chunks_on_disk(rclpy_init, tmp_path):
    from physdyn_ros.msg import ObjectState
    from std_msgs.msg import String

    node = rclpy_init.create_node("bag_pub_kill_chunks")
    states = node.create_publisher(ObjectState, "object_state", RELIABLE)
    chatter = node.create_publisher(String, "chatter", RELIABLE)
    bag = tmp_path / "bag"
    rec = _start_recorder(bag)
    sent: dict[str, list[bytes]] = {"/object_state": [], "/chatter": []}

    def publish(pub, topic, data):
        pub.publish(data)
        sent[topic].append(data)

    try:
        assert wait_until(lambda: states.get_subscription_count() and chatter.get_subscription_count())
        # 1.2 MB of large strings in 1.5 s (a chunk completed by size) with states in between ...
        for i in range(150):
            publish(chatter, "/chatter", string_bytes(f"{i:04d}" + "x" * (BIG - 4)))
            if i % 2 == 0:
                publish(states, "/object_state", object_state_bytes(i))
            time.sleep(0.01)
        # ... then small states at 50 Hz for 2 s (chunks completed by age).
        for i in range(150, 250):
            publish(states, "/object_state", object_state_bytes(i))
            time.sleep(0.02)
        must_have = {t: len(v) for t, v in sent.items()}
        # Within the bound, everything sent is in complete chunks on disk: the open chunk is at most CHUNK_PERIOD
        # old at the next tick (+ DDS / scheduling slack). Wait for that, not for a fixed time.
        assert wait_until(lambda: _on_disk(bag / "bag_0" / "bag_0.mcap") >= must_have,
                          timeout=CHUNK_PERIOD + TICK + 1.5, spin=lambda: time.sleep(0.2)), must_have
        for i in range(250, 255):  # in the open chunk at the kill: may be lost
            publish(states, "/object_state", object_state_bytes(i))
        time.sleep(0.05)
        assert rec.poll() is None, rec.stderr.read()[-2000:]
        rec.kill()  # SIGKILL
        rec.communicate(timeout=20)
    finally:
        if rec.poll() is None:
            rec.kill()
            rec.communicate(timeout=20)
        node.destroy_node()
    assert rec.returncode == -9

    unfinished = bag / "bag_0" / "bag_0.mcap"
    assert unfinished.is_file() and unfinished.stat().st_size > 1_000_000, sorted(bag.rglob("*"))
    assert read_bag(bag) == []  # the bag lists only finished splits: none
    scan = scan_mcap(unfinished)
    assert not scan["footer"]  # really unfinished: no summary, no footer
    assert scan["chunks"] >= 3  # at least one completed by size and two by age
    assert scan["indexed"] >= scan["chunks"]  # each chunk followed by its message index records
    got: dict[str, list[bytes]] = {"/object_state": [], "/chatter": []}
    for topic, _, data in scan["messages"]:
        got[topic].append(data)
    for topic in got:
        assert got[topic] == sent[topic][:len(got[topic])], topic  # in order, byte for byte
        assert len(got[topic]) >= must_have[topic], (topic, len(got[topic]), must_have[topic])
    assert all(t > 1_600_000_000 * 10**9 for _, t, _ in scan["messages"])  # reception times (ns since epoch)
