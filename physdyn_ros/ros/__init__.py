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
"""Message <-> numpy conversions for the physdyn_ros nodes (rclpy message types, numpy; no torch, no pybullet)."""
from .cloud import cloud_size, cloud_to_xyz, xyz_to_cloud
from .convert import (duration_from_sec, duration_to_sec, ns_to_time, pose, pose_to_numpy, quat_angle,
                      quat_to_matrix, quat_yaw, quaternion_to_numpy, time_to_ns, time_to_sec, twist,
                      twist_to_numpy, vector3)
from .trajectory import msg_to_arrays, msg_to_path, object_state, trajectory_markers, trajectory_to_msg

__all__ = ["cloud_size", "cloud_to_xyz", "duration_from_sec", "duration_to_sec", "msg_to_arrays", "msg_to_path",
           "ns_to_time", "object_state", "pose", "pose_to_numpy", "quat_angle", "quat_to_matrix", "quat_yaw",
           "quaternion_to_numpy", "time_to_ns", "time_to_sec", "trajectory_markers", "trajectory_to_msg", "twist",
           "twist_to_numpy", "vector3", "xyz_to_cloud"]
