"""Warnings throttled per reason: rclpy's `throttle_duration_sec` throttles per call site, so one noisy reason
hid every other one (two different bad clouds 1.5 s apart: the second was dropped without a word)."""
from __future__ import annotations

import re
import time
from typing import Callable

#: Numbers in a reason (point counts, ages, values) do not make it another reason.
_NUMBER = re.compile(r"[-+]?\d+(\.\d*)?(e[-+]?\d+)?", re.IGNORECASE)


def reason_key(reason: str) -> str:
    """The kind of a reason: its text with every number replaced by '#'."""
    return _NUMBER.sub("#", reason)


class ReasonThrottle:
    """Log each kind of reason at most once per `period` seconds; says how many of that kind were held back."""

    def __init__(self, log: Callable[[str], None], period: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.log, self.period, self.clock = log, float(period), clock
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
        self.log(text + (f" ({held} more like it since the last one)" if held else ""))
        return True
