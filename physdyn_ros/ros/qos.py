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
"""The suite's QoS profiles: one place for what each topic and service client needs, and why.

Service clients: rclpy's default service QoS keeps the last 10 replies, and every client of a service reads every
reply the server sends (DDS matches them to requests afterwards), so under a burst from several clients a reply
can be pushed out of a client's history before it is read and that client waits forever. A keep-all reply history
loses none; `reliable_client` makes such a client.
"""
from __future__ import annotations

from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: The latest message reaches late joiners: predictions, markers, /tf_static (as tf2_ros's static broadcaster).
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Shape features, latched, deep enough for one message per object of a cloud (a depth of 1 let a reliable writer
#: replace the first objects' features before they were delivered).
FEATURE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Object states keep a deep history: at real_time_factor 0 a whole push is published within milliseconds and a
#: subscriber that wants every frame (the predictor, the demo, a recorder) must not lose the early ones.
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
#: Clouds as a sensor driver publishes them: reliable (REP 2003); consumers may subscribe best effort.
CLOUD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE)
#: Clouds as perception reads them: SensorDataQoS (best effort, volatile) but depth 1: only the newest cloud
#: matters, a slow callback never builds a backlog, and a queue of huge clouds would hold hundreds of MB.
CLOUD_SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                              durability=DurabilityPolicy.VOLATILE)
#: A service client that loses no reply (see the module docstring).
SERVICE_CLIENT_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.VOLATILE)


def reliable_client(node: Any, srv_type: Any, name: str, **kwargs: Any) -> Any:
    """node.create_client(srv_type, name) with SERVICE_CLIENT_QOS: no reply is lost under load."""
    return node.create_client(srv_type, name, qos_profile=SERVICE_CLIENT_QOS, **kwargs)
