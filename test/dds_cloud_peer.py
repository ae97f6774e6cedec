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
"""One side of the dense-cloud DDS test (test_dds_profile.py), run as its own process.

    python dds_cloud_peer.py sub COUNT TIMEOUT   -> prints "ready", then "received N" (best effort, like perception)
    python dds_cloud_peer.py pub COUNT POINTS    -> waits for the subscriber, sends COUNT clouds at 10 Hz (reliable,
                                                    depth 2, like the sim), prints "sent COUNT"
"""
from __future__ import annotations

import sys
import time

import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from physdyn_ros.ros.cloud import xyz_to_cloud


def main() -> int:
    mode, count = sys.argv[1], int(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node(f"dense_cloud_{mode}")
    try:
        if mode == "sub":
            got: list[int] = []
            # A queue as deep as the test: what is lost is lost in transport, not by a slow reader.
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=count, reliability=ReliabilityPolicy.BEST_EFFORT)
            node.create_subscription(PointCloud2, "dense_cloud", lambda m: got.append(m.width), qos)
            print("ready", flush=True)
            deadline = time.monotonic() + float(sys.argv[3])
            while time.monotonic() < deadline and len(got) < count:
                rclpy.spin_once(node, timeout_sec=0.05)
            print(f"received {len(got)}", flush=True)
        else:
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE)
            pub = node.create_publisher(PointCloud2, "dense_cloud", qos)
            deadline = time.monotonic() + 30
            while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            time.sleep(1.0)  # let discovery settle on both sides
            msg = xyz_to_cloud(np.random.default_rng(0).normal(size=(int(sys.argv[3]), 3)).astype(np.float32),
                               "world")
            for _ in range(count):
                pub.publish(msg)
                time.sleep(0.1)
            print(f"sent {count}", flush=True)
            time.sleep(1.0)  # the last fragments leave before the participant goes
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
