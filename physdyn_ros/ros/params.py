"""Declaring node parameters with descriptions and ranges (what `ros2 param describe` shows)."""
from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.node import Node

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def declare(node: Node, name: str, default: Any, description: str, *, read_only: bool = False,
            low: float | None = None, high: float | None = None) -> Any:
    """Declare `name` with `default`, a description and an optional inclusive range; return its value.

    A value outside [low, high] (from a params file or -p) makes declare raise
    rclpy.exceptions.InvalidParameterValueException, so a node fails at start with the parameter named.
    Array parameters need a non-empty default (its element type is the parameter's type).
    """
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
                from_value=float(low if low is not None else -1e300), to_value=float(high if high is not None else 1e300),
                step=0.0)]
    return node.declare_parameter(name, default, desc).value
