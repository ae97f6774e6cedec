"""Declaring node parameters with descriptions and ranges (what `ros2 param describe` shows)."""
from __future__ import annotations

from typing import Any, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def declare(node: Node, name: str, default: Any, description: str, *, read_only: bool = False,
            low: float | None = None, high: float | None = None, choices: Sequence[str] | None = None) -> Any:
    """Declare `name` with `default`, a description and an optional inclusive range or set of values; return
    its value.

    A value outside [low, high] (from a params file or -p) makes declare raise
    rclpy.exceptions.InvalidParameterValueException, so a node fails at start with the parameter named; rclpy
    refuses a later `ros2 param set` out of range with the reason. A string with `choices` is checked the same
    way: at start (ValueError naming the allowed values) and on every set (refused with the reason, never
    replaced in silence). Array parameters need a non-empty default (its element type is the parameter's type).
    """
    if choices is not None:
        description = f"{description} (one of: {', '.join(choices)})"
    desc = ParameterDescriptor(name=name, description=description, read_only=read_only)
    if isinstance(default, list):
        elem = type(default[0])
        desc.type = {float: ParameterType.PARAMETER_DOUBLE_ARRAY, int: ParameterType.PARAMETER_INTEGER_ARRAY,
                     str: ParameterType.PARAMETER_STRING_ARRAY, bool: ParameterType.PARAMETER_BOOL_ARRAY}[elem]
    else:
        desc.type = _TYPES[type(default)]
    if low is not None or high is not None:
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            raise TypeError(f"a range needs a numeric parameter, {name} is {type(default).__name__}")
        if isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(low if low is not None else -2**62),
                                               to_value=int(high if high is not None else 2**62), step=0)]
        else:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(low if low is not None else -1e300),
                to_value=float(high if high is not None else 1e300),
                step=0.0)]
    value = node.declare_parameter(name, default, desc).value
    if choices is not None:
        allowed = _choices(node)
        allowed[name] = tuple(choices)
        if value not in allowed[name]:
            raise ValueError(f"parameter {name} must be one of {', '.join(choices)}, got {value!r}")
    return value


def _choices(node: Node) -> dict[str, tuple[str, ...]]:
    """The node's {name: allowed values}; the first call registers the callback that enforces them on set."""
    registry = getattr(node, "_physdyn_choices", None)
    if registry is None:
        registry = {}
        node._physdyn_choices = registry  # type: ignore[attr-defined]

        def check(params: list[Parameter]) -> SetParametersResult:
            for p in params:
                if p.name in registry and p.value not in registry[p.name]:
                    return SetParametersResult(successful=False, reason=f"{p.name} must be one of "
                                               f"{', '.join(registry[p.name])}, got {p.value!r}")
            return SetParametersResult(successful=True)

        node.add_on_set_parameters_callback(check)
    return registry
