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
"""geometry_msgs / builtin_interfaces <-> numpy (quaternions x, y, z, w as everywhere in physdyn_ros)."""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point, Pose, Quaternion, Twist, Vector3

from .. import geometry as geo
from ..conventions import TOPPLE_ANGLE

NS_PER_S = 1_000_000_000


# ------------------------------------------------------------------------------------------------------- time
def time_to_ns(t: Time) -> int:
    return int(t.sec) * NS_PER_S + int(t.nanosec)


def ns_to_time(ns: int) -> Time:
    sec, nsec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nsec)


def time_to_sec(t: Time) -> float:
    return time_to_ns(t) / NS_PER_S


def duration_from_sec(s: float) -> Duration:
    sec, nsec = divmod(int(round(s * NS_PER_S)), NS_PER_S)
    return Duration(sec=sec, nanosec=nsec)


def duration_to_sec(d: Duration) -> float:
    return int(d.sec) + int(d.nanosec) / NS_PER_S


# ---------------------------------------------------------------------------------------------------- vectors
def vector3(v) -> Vector3:
    x, y, z = (float(c) for c in np.asarray(v, dtype=np.float64).reshape(3))
    return Vector3(x=x, y=y, z=z)


def point(v) -> Point:
    x, y, z = (float(c) for c in np.asarray(v, dtype=np.float64).reshape(3))
    return Point(x=x, y=y, z=z)


def xyz_to_numpy(v: Vector3 | Point) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


def quaternion(q) -> Quaternion:
    x, y, z, w = (float(c) for c in np.asarray(q, dtype=np.float64).reshape(4))
    return Quaternion(x=x, y=y, z=z, w=w)


def quaternion_to_numpy(q: Quaternion, zero_is_identity: bool = False) -> np.ndarray:
    """(x, y, z, w). With zero_is_identity an all-zero quaternion (a default-constructed message) is the identity.

    Raises ValueError for non-finite or zero-norm quaternions; others are normalised.
    """
    arr = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"orientation is not finite: {arr.tolist()}")
    norm = float(np.linalg.norm(arr))
    if norm == 0.0 and zero_is_identity:
        return np.array([0.0, 0.0, 0.0, 1.0])
    if norm < 1e-6:
        raise ValueError("orientation quaternion has zero norm")
    return arr / norm


def pose(position, orientation) -> Pose:
    return Pose(position=point(position), orientation=quaternion(orientation))


def pose_to_numpy(p: Pose, zero_is_identity: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), orientation (x, y, z, w)); raises ValueError when not finite."""
    pos = xyz_to_numpy(p.position)
    if not np.all(np.isfinite(pos)):
        raise ValueError(f"position is not finite: {pos.tolist()}")
    return pos, quaternion_to_numpy(p.orientation, zero_is_identity)


def twist(lin_vel, ang_vel) -> Twist:
    return Twist(linear=vector3(lin_vel), angular=vector3(ang_vel))


def twist_to_numpy(t: Twist) -> tuple[np.ndarray, np.ndarray]:
    """(linear (3,), angular (3,)) as given; the caller checks finiteness and limits."""
    return xyz_to_numpy(t.linear), xyz_to_numpy(t.angular)


# -------------------------------------------------------------------------------------------------- rotations
# scipy.spatial.transform through geometry.py's wrappers; only the project's own rules (yaw of the projected x
# axis, the topple rule) are written here.
def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    return geo.quat_to_matrix(np.asarray(q, dtype=np.float64).reshape(4))


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation about the table's z axis by `yaw` rad."""
    return geo.yaw_quat(float(yaw))


def quat_angle(q1, q2) -> float:
    """Geodesic angle (rad) between two orientations."""
    return float(geo.quat_angle_between(np.asarray(q1, dtype=np.float64).reshape(4),
                                        np.asarray(q2, dtype=np.float64).reshape(4)))


def quat_yaw(q) -> float:
    """Yaw (rad) of the object's x axis projected on the table plane."""
    r = quat_to_matrix(q)
    return math.atan2(r[1, 0], r[0, 0])


def is_toppled(q) -> bool:
    """The object's up axis is tilted more than TOPPLE_ANGLE from the table's up axis: R[2, 2] = 1 - 2 (x^2 + y^2)
    of the unit quaternion, the same arithmetic as trajectory_to_msg's vectorised flags (bit for bit at 45 deg)."""
    x, y = (float(c) for c in np.asarray(q, dtype=np.float64).reshape(4)[:2])
    return bool(1 - 2 * (x * x + y * y) < math.cos(TOPPLE_ANGLE))


def tf_message(pose_xyzq, parent: str, child: str, stamp: Time):
    """tf2_msgs/TFMessage of one transform: child's pose [x, y, z, qx, qy, qz, qw] in parent (needs tf2_msgs)."""
    from geometry_msgs.msg import TransformStamped
    from std_msgs.msg import Header
    from tf2_msgs.msg import TFMessage

    x, y, z, qx, qy, qz, qw = (float(v) for v in pose_xyzq)
    tf = TransformStamped(header=Header(frame_id=parent, stamp=stamp), child_frame_id=child)
    tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = x, y, z
    r = tf.transform.rotation
    r.x, r.y, r.z, r.w = qx, qy, qz, qw
    return TFMessage(transforms=[tf])
