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
"""Predicted trajectories -> physdyn_ros/PredictedTrajectory, nav_msgs/Path and visualization_msgs/MarkerArray.

`trajectory_to_msg` takes any object with the attributes of physdyn_ros.predictor.Trajectory (dt, positions,
orientations, lin_vels, ang_vels, topple_prob), so this module never imports torch.
"""
from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion, Twist, Vector3
from nav_msgs.msg import Path
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from .. import geometry as geo
from ..conventions import TOPPLE_ANGLE
from ..msg import ObjectState, PredictedTrajectory
from .convert import (NS_PER_S, duration_from_sec, duration_to_sec, is_toppled, ns_to_time, point, pose,
                      pose_to_numpy, time_to_ns, twist)

#: Marker namespaces; ids inside them are stable (0 = the path, k = the cube at step k).
PATH_NS = "predicted_path"
BOX_NS = "predicted_pose"


class TrajectoryLike(Protocol):
    dt: float
    positions: np.ndarray  # (H+1, 3)
    orientations: np.ndarray  # (H+1, 4) x, y, z, w
    lin_vels: np.ndarray  # (H+1, 3)
    ang_vels: np.ndarray  # (H+1, 3)
    topple_prob: np.ndarray  # (H+1,)


def stamp_at(stamp: Time, k: int, dt: float) -> Time:
    return ns_to_time(time_to_ns(stamp) + int(round(k * dt * 1e9)))


def object_state(frame_id: str, stamp: Time, object_id: str, position, orientation, lin_vel, ang_vel,
                 topple_probability: float | None = None) -> ObjectState:
    """An ObjectState; `toppled` is computed from the orientation, topple_probability defaults to 0 or 1."""
    toppled = is_toppled(orientation)
    prob = float(toppled) if topple_probability is None else float(topple_probability)
    return ObjectState(header=Header(frame_id=frame_id, stamp=stamp), object_id=object_id,
                       pose=pose(position, orientation), twist=twist(lin_vel, ang_vel), toppled=toppled,
                       topple_probability=prob)


def trajectory_to_msg(traj: TrajectoryLike, frame_id: str, stamp: Time, object_id: str, model_id: str,
                      steps_in: int = 0) -> PredictedTrajectory:
    """states[k] is stamped stamp + k * dt; topple_probability is the highest per-step probability.

    The same message as building each state with object_state (stamp_at, is_toppled), in about a tenth of the
    time (5 ms for 61 states before, 0.3 ms now): the instants and toppled flags are computed for all states at
    once with numpy, every number becomes a Python float in one tolist(), and the nested messages are filled
    slot by slot instead of through their keyword constructors (which build and throw away a default for every
    field they are given).
    """
    pos = np.asarray(traj.positions, dtype=np.float64).reshape(-1, 3)
    n = len(pos)
    quat = np.asarray(traj.orientations, dtype=np.float64).reshape(-1, 4)
    prob = np.asarray(traj.topple_prob, dtype=np.float64).reshape(-1)
    ns = time_to_ns(stamp) + np.round(np.arange(n) * traj.dt * 1e9).astype(np.int64)  # stamp_at, for all k
    sec, nanosec = np.divmod(ns, NS_PER_S)
    x, y = quat[:, 0], quat[:, 1]
    toppled = (1 - 2 * (x * x + y * y) < _COS_TOPPLE).tolist()  # is_toppled: R[2, 2] < cos(TOPPLE_ANGLE)
    rows = np.concatenate([pos, quat, np.asarray(traj.lin_vels, dtype=np.float64).reshape(-1, 3),
                           np.asarray(traj.ang_vels, dtype=np.float64).reshape(-1, 3), prob[:n, None]], 1).tolist()
    if _SLOTS:
        states = _states_by_slot(frame_id, object_id, rows, sec.tolist(), nanosec.tolist(), toppled)
    else:  # message classes without the generated slot layout: the keyword constructors
        states = [ObjectState(header=Header(frame_id=frame_id, stamp=Time(sec=s, nanosec=ns_)), object_id=object_id,
                              pose=Pose(position=Point(x=r[0], y=r[1], z=r[2]),
                                        orientation=Quaternion(x=r[3], y=r[4], z=r[5], w=r[6])),
                              twist=Twist(linear=Vector3(x=r[7], y=r[8], z=r[9]),
                                          angular=Vector3(x=r[10], y=r[11], z=r[12])),
                              toppled=top, topple_probability=r[13])
                  for r, s, ns_, top in zip(rows, sec.tolist(), nanosec.tolist(), toppled)]
    spread = getattr(traj, "spread", None)
    nan = math.nan
    return PredictedTrajectory(header=Header(frame_id=frame_id, stamp=stamp), object_id=object_id,
                               model_id=model_id, time_step=duration_from_sec(traj.dt), steps_in=int(steps_in),
                               states=states, topple_probability=float(prob.max()) if prob.size else 0.0,
                               novelty=float(getattr(traj, "novelty", nan)),
                               rest_position_spread=float(spread.position) if spread is not None else nan,
                               rest_yaw_spread=float(spread.yaw) if spread is not None else nan,
                               topple_probability_spread=float(spread.topple) if spread is not None else nan)


_COS_TOPPLE = math.cos(TOPPLE_ANGLE)
_STATE_TYPES = (Time, Header, Point, Quaternion, Pose, Vector3, Twist, ObjectState)


def _has_slots(cls: type) -> bool:
    """rosidl_generator_py keeps field f in slot _f (and, since Jazzy, the field-check switch in _check_fields)."""
    slots = getattr(cls, "__slots__", ())
    return "_check_fields" in slots and all("_" + f in slots for f in cls.get_fields_and_field_types())


_SLOTS = all(_has_slots(c) for c in _STATE_TYPES)
# what a keyword constructor stores in _check_fields (the ROS_PYTHON_CHECK_FIELDS environment variable)
_CHECK = {c: c()._check_fields for c in _STATE_TYPES} if _SLOTS else {}


def _states_by_slot(frame_id: str, object_id: str, rows: list, sec: list, nanosec: list, toppled: list) -> list:
    """ObjectStates from rows [px py pz qx qy qz qw lx ly lz ax ay az prob] of Python floats, written straight into
    the generated slots (the values are of the fields' types already: nothing for a setter to check)."""
    new = object.__new__
    c_time, c_header, c_point, c_quat, c_pose, c_vec, c_twist, c_state = (_CHECK[c] for c in _STATE_TYPES)
    states = []
    for (px, py, pz, qx, qy, qz, qw, lx, ly, lz, ax, ay, az, p), s, ns, top in zip(rows, sec, nanosec, toppled):
        t = new(Time)
        t._check_fields, t._sec, t._nanosec = c_time, s, ns
        h = new(Header)
        h._check_fields, h._stamp, h._frame_id = c_header, t, frame_id
        position = new(Point)
        position._check_fields, position._x, position._y, position._z = c_point, px, py, pz
        orientation = new(Quaternion)
        orientation._check_fields, orientation._x, orientation._y = c_quat, qx, qy
        orientation._z, orientation._w = qz, qw
        pose_ = new(Pose)
        pose_._check_fields, pose_._position, pose_._orientation = c_pose, position, orientation
        linear = new(Vector3)
        linear._check_fields, linear._x, linear._y, linear._z = c_vec, lx, ly, lz
        angular = new(Vector3)
        angular._check_fields, angular._x, angular._y, angular._z = c_vec, ax, ay, az
        twist_ = new(Twist)
        twist_._check_fields, twist_._linear, twist_._angular = c_twist, linear, angular
        state = new(ObjectState)
        state._check_fields, state._header, state._object_id, state._pose, state._twist = (c_state, h, object_id,
                                                                                           pose_, twist_)
        state._toppled, state._topple_probability = top, p
        states.append(state)
    return states


def msg_to_path(msg: PredictedTrajectory) -> Path:
    """One PoseStamped per predicted state, each stamped with its own future instant."""
    return Path(header=msg.header,
                poses=[PoseStamped(header=s.header, pose=s.pose) for s in msg.states])


def trajectory_markers(msg: PredictedTrajectory, half_extents=None, heading: float = 0.0,
                       box_every: int = 10) -> MarkerArray:
    """DELETEALL, then a LINE_STRIP through the predicted centres (ns PATH_NS, id 0), then CUBE markers with the
    object's half extents every `box_every` steps and at the last step (ns BOX_NS, id = step index).

    half_extents are those of the bounding box in the object's canonical frame, whose yaw at states[0] is
    `heading` (ShapeFeature.heading); each cube follows the object's rotation since states[0]. No cubes when
    half_extents is None.
    """
    header = msg.header
    clear = Marker(header=header, action=Marker.DELETEALL)
    strip = Marker(header=header, ns=PATH_NS, id=0, type=Marker.LINE_STRIP, action=Marker.ADD,
                   scale=Vector3(x=0.005), color=ColorRGBA(r=0.1, g=0.8, b=0.2, a=1.0),
                   points=[s.pose.position for s in msg.states])
    strip.pose.orientation.w = 1.0
    markers = [clear, strip]
    if half_extents is not None and msg.states:
        size = 2.0 * np.asarray(half_extents, dtype=np.float64).reshape(3)
        _, q0 = pose_to_numpy(msg.states[0].pose, zero_is_identity=True)
        box_in_body = geo.quat_multiply(geo.quat_conjugate(q0), geo.yaw_quat(heading))
        last = len(msg.states) - 1
        steps = sorted(set(range(0, last + 1, max(1, int(box_every)))) | {last})
        poses = [pose_to_numpy(msg.states[k].pose, zero_is_identity=True) for k in steps]
        # every cube's orientation in one scipy call (a Rotation product costs ~60 us per call, whatever its size)
        box_quats = geo.quat_multiply(np.array([q for _, q in poses]), box_in_body)
        for k, (pos, _), qb in zip(steps, poses, box_quats):
            s = msg.states[k]
            p = float(np.clip(s.topple_probability, 0.0, 1.0))
            cube = Marker(header=header, ns=BOX_NS, id=k, type=Marker.CUBE, action=Marker.ADD,
                          scale=Vector3(x=size[0], y=size[1], z=size[2]),
                          color=ColorRGBA(r=0.2 + 0.8 * p, g=0.4 * (1 - p), b=1.0 - p, a=0.35 if k < last else 0.7))
            cube.pose.position = point(pos)
            cube.pose.orientation.x, cube.pose.orientation.y, cube.pose.orientation.z, cube.pose.orientation.w = (
                float(c) for c in qb / np.linalg.norm(qb))
            markers.append(cube)
    return MarkerArray(markers=markers)


def msg_to_arrays(msg: PredictedTrajectory) -> dict[str, np.ndarray]:
    """positions (N, 3), orientations (N, 4), lin_vels, ang_vels, topple_prob (N,), dt: back to numpy."""
    pos = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in msg.states]).reshape(-1, 3)
    quat = np.array([[s.pose.orientation.x, s.pose.orientation.y, s.pose.orientation.z, s.pose.orientation.w]
                     for s in msg.states]).reshape(-1, 4)
    lin = np.array([[s.twist.linear.x, s.twist.linear.y, s.twist.linear.z] for s in msg.states]).reshape(-1, 3)
    ang = np.array([[s.twist.angular.x, s.twist.angular.y, s.twist.angular.z] for s in msg.states]).reshape(-1, 3)
    prob = np.array([s.topple_probability for s in msg.states], dtype=np.float64)
    return {"positions": pos, "orientations": quat, "lin_vels": lin, "ang_vels": ang, "topple_prob": prob,
            "dt": np.float64(duration_to_sec(msg.time_step))}
