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
