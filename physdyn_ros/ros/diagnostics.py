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
"""`/diagnostics` (diagnostic_msgs/DiagnosticArray) from a node, at a steady rate, as ROS tools expect
(rqt_robot_monitor, the diagnostic aggregator, Foxglove): one DiagnosticStatus named "<node>: <what>" whose
key/values are the counters the node already keeps; a managed node also reports its lifecycle state
(WARN "not serving" outside active) and why its last transition failed."""
from __future__ import annotations

import time
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from .lifecycle import lifecycle_state

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR

#: (level, message, {key: value}) of the node right now.
Report = tuple[bytes, str, dict[str, object]]


class Diagnostics:
    """Publish `report()` on /diagnostics every `period` s (and on demand with publish())."""

    def __init__(self, node: Node, what: str, report: Callable[[], Report], period: float = 1.0,
                 callback_group=None) -> None:
        self.node, self.report = node, report
        self.name = f"{node.get_name()}: {what}"
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.timer = node.create_timer(period, self.publish, callback_group=callback_group)

    def status(self) -> DiagnosticStatus:
        try:
            level, message, values = self.report()
        except Exception as exc:  # noqa: BLE001 - a broken report is itself a diagnostic
            level, message, values = ERROR, f"diagnostics failed: {type(exc).__name__}: {exc}", {}
        state = lifecycle_state(self.node)
        if state is not None:  # a managed node: its state first; not serving is a WARN (ERROR stays ERROR)
            error = getattr(self.node, "transition_error", "")
            values = {"lifecycle_state": state, "transition_error": error,
                      "refused_inactive": getattr(self.node, "refused_inactive", 0),
                      "callback_errors": getattr(self.node, "callback_errors", 0), **values}
            if state != "active":
                level = max(level, WARN)
                message = f"lifecycle state '{state}': not serving" + (f" ({error})" if error else "")
        return DiagnosticStatus(level=level, name=self.name, message=message,
                                hardware_id=self.node.get_fully_qualified_name(),
                                values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])

    def publish(self) -> None:
        msg = DiagnosticArray(status=[self.status()])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(msg)


class RefusalWindow:
    """WARN for `hold` seconds after the last refusal (a monitor polling once a second must not miss it)."""

    def __init__(self, hold: float = 10.0) -> None:
        self.hold, self.seen, self.last = hold, 0, -float("inf")

    def level(self, refusals: int) -> bytes:
        if refusals != self.seen:
            self.seen, self.last = refusals, time.monotonic()
        return WARN if time.monotonic() - self.last < self.hold else OK
