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
"""Declaring node parameters with descriptions and ranges (what `ros2 param describe` shows)."""
from __future__ import annotations

from typing import Any, Callable, Optional, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


#: A check of a parameter's value: None when it is valid, else the reason (a sentence naming no parameter).
Check = Callable[[Any], Optional[str]]


def declare(node: Node, name: str, default: Any, description: str, *, read_only: bool = False,
            low: float | None = None, high: float | None = None, choices: Sequence[str] | None = None,
            length: int | None = None, check: Check | None = None) -> Any:
    """Declare `name` with `default`, a description and optional constraints; return its value.

    Constraints: an inclusive range [low, high] (for an array parameter: of every element), a set of allowed
    strings (`choices`), an array `length`, and `check`, any further test of the value. Each is enforced when
    the parameter is declared (the default, a params file, `-p`: the node fails at start with the parameter
    named) and on every later set (`ros2 param set`, SetParameters: refused with the reason, nothing changes).
    rclpy itself refuses a value of another type. Array parameters need a non-empty default (its element type
    is the parameter's type).
    """
    if choices is not None:
        description = f"{description} (one of: {', '.join(choices)})"
    if length is not None:
        description = f"{description} ({length} values)"
    desc = ParameterDescriptor(name=name, description=description, read_only=read_only)
    is_array = isinstance(default, list)
    if is_array:
        elem = type(default[0])
        desc.type = {float: ParameterType.PARAMETER_DOUBLE_ARRAY, int: ParameterType.PARAMETER_INTEGER_ARRAY,
                     str: ParameterType.PARAMETER_STRING_ARRAY, bool: ParameterType.PARAMETER_BOOL_ARRAY}[elem]
    else:
        desc.type = _TYPES[type(default)]
    scalar = default[0] if is_array else default
    if (low is not None or high is not None) and (isinstance(scalar, bool) or not isinstance(scalar, (int, float))):
        raise TypeError(f"a range needs a numeric parameter, {name} is {type(default).__name__}")
    if (low is not None or high is not None) and not is_array:
        if isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(low if low is not None else -2**62),
                                               to_value=int(high if high is not None else 2**62), step=0)]
        else:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(low if low is not None else -1e300),
                to_value=float(high if high is not None else 1e300),
                step=0.0)]
    checks: list[Check] = []
    if choices is not None:
        allowed = tuple(choices)
        checks.append(lambda v: None if v in allowed else f"must be one of {', '.join(allowed)}, got {v!r}")
    if length is not None:
        checks.append(lambda v: None if len(v) == length else f"needs {length} values, got {len(v)}: {list(v)}")
    if is_array and (low is not None or high is not None):
        checks.append(lambda v: _elements_in_range(v, low, high))
    if check is not None:
        checks.append(check)
    value = node.declare_parameter(name, default, desc).value
    reason = first_failure(checks, value)
    if reason is not None:
        raise ValueError(f"parameter {name} {reason}")
    _checks(node)[name] = checks  # from now on every set is checked
    return value


def first_failure(checks: Sequence[Check], value: Any) -> str | None:
    """The first reason one of `checks` gives for `value`, or None when all pass."""
    for c in checks:
        reason = c(value)
        if reason is not None:
            return reason
    return None


def _elements_in_range(values: Sequence[float], low: float | None, high: float | None) -> str | None:
    for v in values:
        if (low is not None and v < low) or (high is not None and v > high):
            lo = "-inf" if low is None else f"{low:g}"
            hi = "inf" if high is None else f"{high:g}"
            return f"needs every value in [{lo}, {hi}], got {list(values)}"
    return None


def _checks(node: Node) -> dict[str, list[Check]]:
    """The node's {name: checks}; the first call registers the callback that enforces them on set."""
    registry = getattr(node, "_physdyn_checks", None)
    if registry is None:
        registry = {}
        node._physdyn_checks = registry  # type: ignore[attr-defined]

        def on_set(params: list[Parameter]) -> SetParametersResult:
            for p in params:
                reason = first_failure(registry.get(p.name, ()), p.value)
                if reason is not None:
                    return SetParametersResult(successful=False, reason=f"{p.name} {reason}")
            return SetParametersResult(successful=True)

        node.add_on_set_parameters_callback(on_set)
    return registry
