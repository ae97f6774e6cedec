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
"""Conventions shared by every part of physdyn_ros (REP 103 units and frames).

All quantities are SI: metres, seconds, kilograms, radians, newton-seconds for impulses.
The table frame is right-handed with z up; the support plane is z = 0.
Quaternions are ordered (x, y, z, w), as in geometry_msgs/Quaternion.
"""
from __future__ import annotations

#: Time between two recorded / predicted states, seconds (15 Hz, as in the paper).
DT: float = 1.0 / 15.0
#: Standard gravity, m/s^2 (points along -z).
GRAVITY: float = 9.81
#: An object counts as toppled once the angle between its up axis and world up exceeds this (radians).
TOPPLE_ANGLE: float = 0.7853981633974483  # 45 degrees
#: Default fixed frame of the table (REP 105 name for a world-fixed frame).
TABLE_FRAME: str = "world"
#: Points in the canonical object cloud fed to the shape encoder.
NUM_POINTS: int = 1024
#: The rest rule (simulator, sim node, bag conversion, predictor): an object is at rest once slower than these ...
REST_LIN_VEL: float = 0.01  # m/s
REST_ANG_VEL: float = 0.05  # rad/s
#: ... for this many consecutive 1/15 s frames (the simulator and bags; a prediction rests at its first quiet step).
REST_FRAMES: int = 4

#: Environment variable `physdyn up` sets to its pid: a node whose parent is gone (killed, even with SIGKILL)
#: stops itself (physdyn_ros.ros.run).
PARENT_PID_ENV = "PHYSDYN_PARENT_PID"
