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
"""Messages throttled per reason, at a fixed severity.

rclpy's `throttle_duration_sec` throttles per call site, so one noisy reason would hide every other one; this
class throttles per kind of reason instead. rclpy also binds one severity to each call site (a second severity
there raises "Logger severity cannot be changed between calls"), so every severity is logged from its own line.
"""
from __future__ import annotations

import re
import time
from typing import Any, Callable

#: Numbers in a reason (point counts, ages, values) do not make it another reason.
_NUMBER = re.compile(r"[-+]?\d+(\.\d*)?(e[-+]?\d+)?", re.IGNORECASE)
SEVERITIES = ("debug", "info", "warning", "error", "fatal")


def reason_key(reason: str) -> str:
    """The kind of a reason: its text with every number replaced by '#'."""
    return _NUMBER.sub("#", reason)


def log_at(logger: Any, severity: str, text: str) -> None:
    """Log `text` at `severity` on an rclpy logger, one call site per severity (see the module docstring)."""
    if severity == "debug":
        logger.debug(text)
    elif severity == "info":
        logger.info(text)
    elif severity == "warning":
        logger.warning(text)
    elif severity == "error":
        logger.error(text)
    elif severity == "fatal":
        logger.fatal(text)
    else:
        raise ValueError(f"severity must be one of {', '.join(SEVERITIES)}, got {severity!r}")


class ReasonThrottle:
    """Log each kind of reason at most once per `period` seconds; says how many of that kind were held back.

    `logger` is an rclpy logger (or anything with debug/info/warning/error/fatal methods) and `severity` one of
    SEVERITIES; several throttles of different severities may share one logger.
    """

    def __init__(self, logger: Any, severity: str, period: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if severity not in SEVERITIES:
            raise ValueError(f"severity must be one of {', '.join(SEVERITIES)}, got {severity!r}")
        self.logger, self.severity, self.period, self.clock = logger, severity, float(period), clock
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def __call__(self, text: str, reason: str) -> bool:
        """Log `text` unless a message of the same reason kind was logged less than `period` s ago."""
        key, now = reason_key(reason), self.clock()
        last = self._last.get(key)
        if last is not None and now - last < self.period:
            self._held[key] = self._held.get(key, 0) + 1
            return False
        held = self._held.pop(key, 0)
        self._last[key] = now
        log_at(self.logger, self.severity, text + (f" ({held} more like it since the last one)" if held else ""))
        return True
