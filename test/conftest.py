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
"""Shared test setup: a private DDS domain on loopback, the repository paths, and an rclpy fixture."""
from __future__ import annotations

import os
import random
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable

# Talk over loopback only, on a domain of our own, so parallel test runs on one machine do not see each
# other. Set before rclpy initialises anywhere (subprocesses inherit it).
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
if "PHYSDYN_TEST_DOMAIN" not in os.environ:
    os.environ["PHYSDYN_TEST_DOMAIN"] = str(random.SystemRandom().randint(1, 100))
os.environ["ROS_DOMAIN_ID"] = os.environ["PHYSDYN_TEST_DOMAIN"]


@pytest.fixture(scope="session")
def rclpy_init():
    """Initialise rclpy once for the test process; shut down at the end."""
    import rclpy

    rclpy.init()
    yield rclpy
    rclpy.try_shutdown()
