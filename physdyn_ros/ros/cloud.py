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
"""sensor_msgs/PointCloud2 <-> numpy, without sensor_msgs_py (not on PyPI) and without copying the whole buffer.

Reading (`cloud_to_xyz`, `cloud_size`) is the package's one PointCloud2 reader, physdyn_ros.perception.pointcloud2
(ROS-free, so bag tools share it): fields are read by name, any cloud whose x, y and z are FLOAT32 fields with
count 1 is accepted, anything else raises ValueError naming the problem. Writing (`xyz_to_cloud`) builds rclpy
messages, so it lives here.
"""
from __future__ import annotations

import array
import sys

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from ..perception.pointcloud2 import XYZ, cloud_size, cloud_to_xyz

__all__ = ["XYZ", "cloud_size", "cloud_to_xyz", "xyz_to_cloud"]


def xyz_to_cloud(points: np.ndarray, frame_id: str, stamp: Time | None = None) -> PointCloud2:
    """An unorganized xyz float32 PointCloud2 (point_step 12, host byte order), like create_cloud_xyz32."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3))
    data = array.array("B")
    data.frombytes(pts.tobytes())
    return PointCloud2(
        header=Header(frame_id=frame_id, stamp=stamp if stamp is not None else Time()),
        height=1, width=len(pts),
        fields=[PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate(XYZ)],
        is_bigendian=sys.byteorder != "little", point_step=12, row_step=12 * len(pts),
        data=data, is_dense=bool(np.isfinite(pts).all()))
