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
"""trajectory_to_msg (vectorised) serializes to the same bytes as the previous implementation.

The previous implementation is kept below as the reference. rclpy's serializer leaves the CDR alignment padding
uninitialised (two serializations of one message can differ there), so the bytes are compared field by field:
`cdr_fields` walks the serialized buffer with the message definition and keeps every field's bytes, in order,
dropping only the padding; it must consume the whole buffer.
"""
from __future__ import annotations

import importlib
import math
import struct
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser.definition import AbstractSequence, AbstractString, BasicType, NamespacedType
from std_msgs.msg import Header

from physdyn_ros import geometry as geo
from physdyn_ros.msg import ObjectState, PredictedTrajectory
from physdyn_ros.ros.convert import duration_from_sec, is_toppled, ns_to_time, pose, time_to_ns, twist
from physdyn_ros.ros.trajectory import msg_to_arrays, msg_to_path, trajectory_to_msg
from physdyn_ros.spread import RestSpread


# ---------------------------------------------------------------------------- the previous implementation
def old_stamp_at(stamp: Time, k: int, dt: float) -> Time:
    return ns_to_time(time_to_ns(stamp) + int(round(k * dt * 1e9)))


def old_object_state(frame_id, stamp, object_id, position, orientation, lin_vel, ang_vel, topple_probability=None):
    toppled = is_toppled(orientation)
    prob = float(toppled) if topple_probability is None else float(topple_probability)
    return ObjectState(header=Header(frame_id=frame_id, stamp=stamp), object_id=object_id,
                       pose=pose(position, orientation), twist=twist(lin_vel, ang_vel), toppled=toppled,
                       topple_probability=prob)


def old_trajectory_to_msg(traj, frame_id, stamp, object_id, model_id, steps_in=0):
    prob = np.asarray(traj.topple_prob, dtype=np.float64).reshape(-1)
    states = [old_object_state(frame_id, old_stamp_at(stamp, k, traj.dt), object_id, traj.positions[k],
                               traj.orientations[k], traj.lin_vels[k], traj.ang_vels[k], prob[k])
              for k in range(len(traj.positions))]
    return PredictedTrajectory(header=Header(frame_id=frame_id, stamp=stamp), object_id=object_id,
                               model_id=model_id, time_step=duration_from_sec(traj.dt), steps_in=int(steps_in),
                               states=states, topple_probability=float(prob.max()) if prob.size else 0.0,
                               novelty=float(traj.novelty),  # the field added with the topple head
                               # and those added with the spread
                               rest_position_spread=float(traj.spread.position),
                               rest_yaw_spread=float(traj.spread.yaw),
                               topple_probability_spread=float(traj.spread.topple))


# ------------------------------------------------------------------------------------- CDR field bytes
_SIZES = {"boolean": 1, "octet": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
          "uint32": 4, "float": 4, "int64": 8, "uint64": 8, "double": 8}


def cdr_fields(buf: bytes, cls: type) -> bytes:
    """Every field's bytes of a serialized message (little-endian CDR), in order, without alignment padding."""
    assert buf[:2] == b"\x00\x01", "expected little-endian CDR"
    out = bytearray()
    pos = 4  # after the encapsulation header; alignment counts from here

    def take(n: int, align: int) -> bytes:
        nonlocal pos
        pos = 4 + -(-(pos - 4) // align) * align
        chunk = buf[pos:pos + n]
        assert len(chunk) == n, "buffer too short for the message definition"
        out.extend(chunk)
        pos += n
        return chunk

    def walk(t) -> None:
        if isinstance(t, NamespacedType):
            sub = getattr(importlib.import_module(".".join(t.namespaces)), t.name)
            for field_type in sub.SLOT_TYPES:
                walk(field_type)
        elif isinstance(t, BasicType):
            take(_SIZES[t.typename], _SIZES[t.typename])
        elif isinstance(t, AbstractString):
            (length,) = struct.unpack("<I", take(4, 4))
            take(length, 1)
        elif isinstance(t, AbstractSequence):
            (count,) = struct.unpack("<I", take(4, 4))
            for _ in range(count):
                walk(t.value_type)
        else:
            raise NotImplementedError(t)

    for field_type in cls.SLOT_TYPES:
        walk(field_type)
    assert len(buf) - pos < 8, f"{len(buf) - pos} bytes left over after the message definition"
    return bytes(out)


def same_serialization(new, old) -> bool:
    a, b = serialize_message(new), serialize_message(old)
    return len(a) == len(b) and cdr_fields(a, PredictedTrajectory) == cdr_fields(b, PredictedTrajectory)


# ----------------------------------------------------------------------------------------------- cases
def fake_trajectory(rng, n: int, dt: float, tilt: float = 1.5) -> SimpleNamespace:
    """Random states: orientations tilted up to `tilt` rad (some toppled, some not), probabilities in [0, 1]."""
    axis = rng.normal(size=(n, 3)) * [1.0, 1.0, 0.2]
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    tilted = geo.axis_angle_to_quat(axis * rng.uniform(0, tilt, (n, 1)))
    q = geo.quat_multiply(tilted, geo.yaw_quat(rng.uniform(-np.pi, np.pi, n)))
    return SimpleNamespace(dt=dt, positions=rng.normal(size=(n, 3)), orientations=q,
                           lin_vels=rng.normal(size=(n, 3)), ang_vels=rng.normal(size=(n, 3)) * 3,
                           topple_prob=rng.uniform(size=n), novelty=float(rng.uniform(0, 2)),
                           spread=RestSpread(0.9, *rng.uniform(0, 0.1, 3), (0.0, 0.0)))


@pytest.mark.parametrize("n, dt, stamp_ns", [
    (61, 1 / 15, 1_700_000_000_123_456_789),
    (1, 1 / 15, 0),
    (2, 0.1, 999_999_999),  # states cross a second boundary
    (151, 1 / 30, 1_234_567_890_999_999_000),
    (40, 0.0123456789, 5),
])
def test_same_bytes_as_the_previous_implementation(n, dt, stamp_ns):
    rng = np.random.default_rng(n)
    stamp = ns_to_time(stamp_ns)
    for trial in range(3):
        traj = fake_trajectory(rng, n, dt)
        args = (traj, "table" * trial or "w", stamp, "object_" + "x" * trial, "model-" + "abc"[:trial], trial)
        new, old = trajectory_to_msg(*args), old_trajectory_to_msg(*args)
        assert new == old
        assert same_serialization(new, old)
        back = [deserialize_message(serialize_message(m), PredictedTrajectory) for m in (new, old)]
        assert back[0] == back[1]  # (float32 fields round, the same way for both)
        assert [s.toppled for s in new.states] == [bool(is_toppled(q)) for q in traj.orientations]


def test_a_trajectory_without_spread_carries_nan():
    traj = fake_trajectory(np.random.default_rng(1), 3, 1 / 15)
    traj.spread = None
    msg = trajectory_to_msg(traj, "w", ns_to_time(1), "box", "m")
    assert all(math.isnan(x) for x in (msg.rest_position_spread, msg.rest_yaw_spread, msg.topple_probability_spread))


def test_same_bytes_for_float32_inputs_and_an_edge_of_toppling():
    rng = np.random.default_rng(0)
    traj = fake_trajectory(rng, 61, 1 / 15)
    # exactly 45 degrees and a hair either side: the toppled flag must agree with is_toppled bit for bit
    for k, angle in enumerate((math.pi / 4, math.pi / 4 - 1e-12, math.pi / 4 + 1e-12)):
        traj.orientations[k] = geo.axis_angle_to_quat(np.array([angle, 0.0, 0.0]))
    as32 = SimpleNamespace(**{k: (v.astype(np.float32) if isinstance(v, np.ndarray) else v)
                              for k, v in vars(traj).items()})
    for t in (traj, as32):
        args = (t, "world", ns_to_time(42), "box", "m")
        assert same_serialization(trajectory_to_msg(*args), old_trajectory_to_msg(*args))


def test_predicted_trajectory_of_the_shipped_model():
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load()
    rng = np.random.default_rng(3)
    cloud = rng.normal(size=(300, 3)) * [0.08, 0.04, 0.06] + [0.5, -0.2, 0.06]
    for v, w in (([0.6, 0.1, 0.0], [0.0, 0.0, 2.0]), ([1.4, -0.5, 0.0], [3.0, 0.0, 1.0])):
        traj = pred.rollout(cloud, v, w, horizon=60, spread=True)
        args = (traj, "table", ns_to_time(1_700_000_000_000_000_000), "mug_1", pred.model_id, 2)
        new, old = trajectory_to_msg(*args), old_trajectory_to_msg(*args)
        assert same_serialization(new, old)
        # the path and arrays built from it are unchanged too
        assert msg_to_path(new) == msg_to_path(old)
        back = msg_to_arrays(new)
        assert np.array_equal(back["positions"], traj.positions) and back["positions"].shape == (61, 3)


def test_cdr_fields_sees_every_byte_of_a_field():
    traj = fake_trajectory(np.random.default_rng(1), 3, 0.1)
    msg = trajectory_to_msg(traj, "w", ns_to_time(0), "o", "m")
    other = trajectory_to_msg(traj, "w", ns_to_time(0), "o", "m")
    other.states[2].pose.position.z = np.nextafter(other.states[2].pose.position.z, np.inf)
    assert not same_serialization(msg, other)
