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
"""`physdyn replay`: the recorded bytes come out again, with the recorded timing (or --rate times faster)."""
from __future__ import annotations

import subprocess
import threading
import time

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from conftest import PYTHON, ROOT
from physdyn_ros.bag.writer import BagWriter
from test_bag_support import OBJECT_STATE, object_state_bytes, string_bytes

T0 = 1_700_000_000_000_000_000
PERIOD = 50_000_000  # ns between recorded states


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "bag"
    w = BagWriter(path, split_duration=None, split_size=4000)  # several files: replay must cross them
    w.open()
    a = w.add_topic("/object_state", OBJECT_STATE)
    b = w.add_topic("/chatter", "std_msgs/msg/String")
    for k in range(40):
        w.write(a, T0 + k * PERIOD, object_state_bytes(k))
        if k % 5 == 0:
            w.write(b, T0 + k * PERIOD + 1, string_bytes(f"tick{k:03d}"))
    w.close()
    assert len(w.files) > 1
    return path


class Listener:
    def __init__(self, rclpy, name: str) -> None:
        from physdyn_ros.msg import ObjectState
        from std_msgs.msg import String

        self.node = rclpy.create_node(name)
        self.got: dict[str, list[tuple[float, bytes]]] = {"/object_state": [], "/chatter": []}
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        for topic, cls in (("/object_state", ObjectState), ("/chatter", String)):
            self.node.create_subscription(cls, topic, lambda d, t=topic: self.got[t].append((time.monotonic(), d)),
                                          qos, raw=True)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def spin_while(self, busy) -> None:
        while busy():
            self.executor.spin_once(timeout_sec=0.01)
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_replay_keeps_bytes_and_timing(rclpy_init, bag, rate):
    from physdyn_ros.ros.replay import replay

    listener = Listener(rclpy_init, f"replay_listener_{int(rate)}")
    pub_node = rclpy_init.create_node(f"replay_pub_{int(rate)}")
    result: dict = {}
    thread = threading.Thread(target=lambda: result.update(replay(bag, rate=rate, delay=5.0, node=pub_node,
                                                                  log=lambda s: None)))
    thread.start()
    listener.spin_while(thread.is_alive)
    thread.join()
    pub_node.destroy_node()
    listener.close()
    assert result["messages"] == 48
    states = listener.got["/object_state"]
    assert [d for _, d in states] == [object_state_bytes(k) for k in range(40)]
    assert [d for _, d in listener.got["/chatter"]] == [string_bytes(f"tick{k:03d}") for k in range(0, 40, 5)]
    arrival = np.array([t for t, _ in states]) - states[0][0]
    expected = np.arange(40) * PERIOD / 1e9 / rate
    err = np.abs(arrival - expected)
    assert np.median(err) < 0.01 and err.max() < 0.06, (rate, err.round(4).tolist())


def test_replay_cli(rclpy_init, bag):
    listener = Listener(rclpy_init, "replay_listener_cli")
    proc = subprocess.Popen([PYTHON, "-m", "physdyn_ros.cli", "replay", str(bag), "--rate", "10", "--delay", "10"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    listener.spin_while(lambda: proc.poll() is None)
    out, err = proc.communicate(timeout=30)
    listener.close()
    assert proc.returncode == 0, err
    assert "replayed 48 messages on 2 topic(s)" in out
    assert [d for _, d in listener.got["/object_state"]] == [object_state_bytes(k) for k in range(40)]
    bad = subprocess.run([PYTHON, "-m", "physdyn_ros.cli", "replay", str(bag), "--topics", "/nope"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "topics ['/nope'] are not in" in bad.stderr
