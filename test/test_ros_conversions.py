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
"""Message <-> numpy conversions (physdyn_ros.ros): real message types, no graph."""
from __future__ import annotations

import array
import math
import time
import tracemalloc
from types import SimpleNamespace

import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2, PointField

from physdyn_ros.msg import PredictedTrajectory
from physdyn_ros.ros import cloud_to_xyz, msg_to_arrays, msg_to_path, trajectory_markers, trajectory_to_msg, \
    xyz_to_cloud
from physdyn_ros.ros.convert import (duration_to_sec, ns_to_time, pose, pose_to_numpy, quat_to_matrix,
                                     quaternion_to_numpy, time_to_ns)
from visualization_msgs.msg import Marker

F32, U8, F64 = PointField.FLOAT32, PointField.UINT8, PointField.FLOAT64


def make_cloud(points: np.ndarray, fields: list[tuple[str, int, str]], point_step: int, bigendian: bool = False,
               height: int = 1, row_pad: int = 0, extra: dict[str, np.ndarray] | None = None) -> PointCloud2:
    """A cloud with arbitrary fields (name, offset, numpy type) laid out by hand, like a driver would."""
    n = len(points)
    width = n // height
    order = ">" if bigendian else "<"
    dtype = np.dtype({"names": [f[0] for f in fields], "formats": [order + f[2] for f in fields],
                      "offsets": [f[1] for f in fields], "itemsize": point_step})
    rec = np.zeros(n, dtype=dtype)
    for i, name in enumerate("xyz"):
        if name in rec.dtype.names:
            rec[name] = points[:, i]
    for name, values in (extra or {}).items():
        rec[name] = values
    rows = rec.view(np.uint8).reshape(height, width * point_step)
    rows = np.concatenate([rows, np.full((height, row_pad), 0xAB, np.uint8)], axis=1)
    kind = {"f4": F32, "u1": U8, "f8": F64}
    data = array.array("B")
    data.frombytes(rows.tobytes())
    return PointCloud2(height=height, width=width, is_bigendian=bigendian, point_step=point_step,
                       row_step=width * point_step + row_pad, data=data, is_dense=False,
                       fields=[PointField(name=f[0], offset=f[1], datatype=kind[f[2]], count=1) for f in fields])


@pytest.fixture
def pts() -> np.ndarray:
    return np.random.default_rng(1).normal(size=(24, 3)).astype(np.float32)


def test_roundtrip_xyz_cloud(pts):
    msg = xyz_to_cloud(pts, "world")
    assert msg.point_step == 12 and msg.row_step == 12 * len(pts) and msg.height == 1 and msg.is_dense
    assert [f.name for f in msg.fields] == ["x", "y", "z"]
    np.testing.assert_array_equal(cloud_to_xyz(msg), pts)


@pytest.mark.parametrize("bigendian", [False, True])
def test_reads_padded_reordered_fields_any_byte_order(pts, bigendian):
    # 32-byte points: rgb first, z before x, intensity float64 after: x, y, z found by name, not by position.
    fields = [("rgb", 0, "u1"), ("z", 4, "f4"), ("x", 12, "f4"), ("y", 16, "f4"), ("intensity", 20, "f8")]
    msg = make_cloud(pts, fields, 32, bigendian=bigendian, extra={"intensity": np.arange(len(pts)) * 1.5})
    got = cloud_to_xyz(msg)
    assert got.dtype == np.float32 and got.dtype.isnative
    np.testing.assert_array_equal(got, pts)


def test_organized_cloud_with_row_padding_and_nans(pts):
    pts = pts.copy()
    pts[3] = np.nan  # invalid pixel
    pts[7, 2] = np.inf
    msg = make_cloud(pts, [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")], 16, height=4, row_pad=8)
    assert msg.height == 4 and msg.row_step == 6 * 16 + 8
    finite = np.isfinite(pts).all(1)
    np.testing.assert_array_equal(cloud_to_xyz(msg), pts[finite])
    assert len(cloud_to_xyz(msg, skip_nans=False)) == len(pts)


@pytest.mark.parametrize("fields, step, reason", [
    ([("x", 0, "f4"), ("y", 4, "f4")], 12, "no z field"),
    ([("x", 0, "f8"), ("y", 8, "f8"), ("z", 16, "f8")], 24, "datatype 8, expected FLOAT32"),
    ([("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")], 10, "does not fit in point_step 10"),
    ([("rgb", 0, "u1")], 4, "no x/y/z field"),
])
def test_other_layouts_are_refused_with_the_reason(pts, fields, step, reason):
    if step == 10:  # a header claiming a point_step its fields do not fit in
        msg = make_cloud(pts, fields, 12)
        msg.point_step = 10
    else:
        msg = make_cloud(pts, fields, step)
    with pytest.raises(ValueError, match=reason):
        cloud_to_xyz(msg)


def test_truncated_data_and_bad_row_step_are_refused(pts):
    msg = xyz_to_cloud(pts, "world")
    msg.data = msg.data[:-5]
    with pytest.raises(ValueError, match="expected row_step \\* height"):
        cloud_to_xyz(msg)
    msg = xyz_to_cloud(pts, "world")
    msg.row_step = 11
    with pytest.raises(ValueError, match="row_step 11 is smaller"):
        cloud_to_xyz(msg)
    count3 = xyz_to_cloud(pts, "world")
    count3.fields[0].count = 3
    with pytest.raises(ValueError, match="count 3"):
        cloud_to_xyz(count3)


def test_empty_cloud_gives_no_points():
    assert cloud_to_xyz(xyz_to_cloud(np.zeros((0, 3)), "world")).shape == (0, 3)


def test_huge_cloud_is_read_in_bounded_time_and_memory():
    n = 10_000_000
    big = np.zeros((n, 3), np.float32)
    big[:, 0] = np.arange(n, dtype=np.float32)
    msg = xyz_to_cloud(big, "world")
    del big
    tracemalloc.start()
    t0 = time.monotonic()
    got = cloud_to_xyz(msg, max_points=50_000, rng=np.random.default_rng(0))
    elapsed = time.monotonic() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert got.shape == (50_000, 3)
    assert len(np.unique(got[:, 0])) == 50_000  # distinct points, spread over the whole cloud
    assert got[:, 0].max() > 0.9 * n and got[:, 0].min() < 0.1 * n
    assert peak < 20e6, f"reading 50k of 10M points allocated {peak / 1e6:.0f} MB"
    assert elapsed < 2.0, f"{elapsed:.2f} s"


def test_time_and_pose_helpers():
    t = ns_to_time(1_500_000_123)
    assert (t.sec, t.nanosec) == (1, 500_000_123) and time_to_ns(t) == 1_500_000_123
    q = np.array([0.1, -0.2, 0.3, 0.9])
    p, qq = pose_to_numpy(pose([1, 2, 3], q))
    np.testing.assert_allclose(p, [1, 2, 3])
    np.testing.assert_allclose(qq, q / np.linalg.norm(q))
    np.testing.assert_allclose(quat_to_matrix(qq) @ quat_to_matrix(qq).T, np.eye(3), atol=1e-12)
    zero = pose([0, 0, 0], [0, 0, 0, 0]).orientation
    np.testing.assert_array_equal(quaternion_to_numpy(zero, zero_is_identity=True), [0, 0, 0, 1])
    with pytest.raises(ValueError, match="zero norm"):
        quaternion_to_numpy(zero)
    with pytest.raises(ValueError, match="not finite"):
        pose_to_numpy(pose([math.nan, 0, 0], [0, 0, 0, 1]))


def fake_trajectory(h: int = 30) -> SimpleNamespace:
    """A trajectory object with the Predictor's Trajectory attributes: slide along x, spinning about z."""
    k = np.arange(h + 1)
    yaw = 0.05 * k
    quat = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], 1)
    pos = np.stack([0.01 * k, np.zeros_like(yaw), np.full_like(yaw, 0.05)], 1)
    return SimpleNamespace(dt=1 / 15, positions=pos, orientations=quat, lin_vels=np.tile([0.15, 0, 0], (h + 1, 1)),
                           ang_vels=np.tile([0, 0, 0.75], (h + 1, 1)), topple_prob=np.linspace(0, 0.4, h + 1))


def test_trajectory_to_messages():
    traj = fake_trajectory()
    stamp = ns_to_time(10**9 * 100)
    msg = trajectory_to_msg(traj, "world", stamp, "mug_1", "model-abc", steps_in=2)
    assert isinstance(msg, PredictedTrajectory)
    assert len(msg.states) == 31 and msg.steps_in == 2 and msg.model_id == "model-abc"
    assert duration_to_sec(msg.time_step) == pytest.approx(1 / 15, abs=1e-9)
    assert msg.topple_probability == pytest.approx(0.4)
    # states[k] at stamp + k * dt, all in the table frame
    assert time_to_ns(msg.states[15].header.stamp) - time_to_ns(stamp) == pytest.approx(10**9, abs=2)
    assert {s.header.frame_id for s in msg.states} == {"world"} and {s.object_id for s in msg.states} == {"mug_1"}
    assert not any(s.toppled for s in msg.states)
    back = msg_to_arrays(msg)
    np.testing.assert_allclose(back["positions"], traj.positions)
    np.testing.assert_allclose(back["orientations"], traj.orientations)
    np.testing.assert_allclose(back["ang_vels"], traj.ang_vels)
    path = msg_to_path(msg)
    assert path.header.frame_id == "world" and len(path.poses) == 31
    assert path.poses[30].header.stamp == msg.states[30].header.stamp
    assert path.poses[30].pose.position.x == pytest.approx(0.3)


def test_markers_clear_first_and_have_stable_ids():
    msg = trajectory_to_msg(fake_trajectory(), "world", ns_to_time(5), "box", "m")
    arr = trajectory_markers(msg, half_extents=[0.05, 0.02, 0.03], heading=0.3, box_every=10)
    ms = arr.markers
    assert ms[0].action == Marker.DELETEALL
    assert ms[1].type == Marker.LINE_STRIP and len(ms[1].points) == 31 and ms[1].scale.x > 0
    cubes = ms[2:]
    assert [m.id for m in cubes] == [0, 10, 20, 30] and {m.ns for m in cubes} == {"predicted_pose"}
    assert all(m.type == Marker.CUBE for m in cubes)
    assert (cubes[0].scale.x, cubes[0].scale.y, cubes[0].scale.z) == pytest.approx((0.1, 0.04, 0.06))
    # the box is yawed by the heading at k = 0, then turns with the object (yaw 0.05 per step)
    for m in cubes:
        q = m.pose.orientation
        assert 2 * math.atan2(q.z, q.w) == pytest.approx(0.3 + 0.05 * m.id)
    assert all(m.header.frame_id == "world" for m in ms)
    # no extents: only the clear marker and the path
    assert len(trajectory_markers(msg).markers) == 2


@pytest.mark.parametrize("layout", ["plain", "padded_bigendian", "bad_datatype"])
def test_bag_clouds_go_through_the_same_reader(pts, layout):
    """One PointCloud2 reader. A cloud serialized by rclpy and deserialized by rosbags (as the bag
    tools read it, without rclpy) gives the same points, or the same refusal, as the rclpy message."""
    from rclpy.serialization import serialize_message

    from physdyn_ros.bag.pushes import cloud_xyz
    from physdyn_ros.bag.types import deserialize

    pts = pts.copy()
    pts[3] = np.nan
    if layout == "plain":
        msg = xyz_to_cloud(pts, "world")
    elif layout == "padded_bigendian":
        msg = make_cloud(pts, [("rgb", 0, "u1"), ("z", 4, "f4"), ("x", 8, "f4"), ("y", 12, "f4")], 20,
                         bigendian=True, height=2, row_pad=8)
    else:
        msg = make_cloud(pts, [("x", 0, "f8"), ("y", 8, "f8"), ("z", 16, "f8")], 24)
    bag_msg = deserialize(serialize_message(msg), "sensor_msgs/msg/PointCloud2")
    if layout == "bad_datatype":
        with pytest.raises(ValueError) as ros_err:
            cloud_to_xyz(msg)
        with pytest.raises(ValueError) as bag_err:
            cloud_xyz(bag_msg)
        assert str(bag_err.value) == str(ros_err.value) and "expected FLOAT32" in str(ros_err.value)
        return
    got = cloud_xyz(bag_msg)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, cloud_to_xyz(msg).astype(np.float64))
    np.testing.assert_array_equal(got, pts[np.isfinite(pts).all(axis=1)].astype(np.float64))
