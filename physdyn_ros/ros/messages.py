"""rclpy message classes by their ROS type name (the recorder subscribes, the replay publishes, by name)."""
from __future__ import annotations

import importlib


def message_class(msgtype: str) -> type:
    """The rclpy message class of 'pkg/msg/Type' (ValueError if this machine has no Python interface for it)."""
    package, _, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype} has no Python interface on this machine (cannot import "
                         f"{package}.msg.{name}; build and source the package that defines it)") from None
