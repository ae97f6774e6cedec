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
"""sensor_msgs/PointCloud2 layout -> numpy, on the message's fields only: no rclpy, no sensor_msgs import.

The one PointCloud2 reader of the package. It works on any object with a PointCloud2's attributes (fields with
name / offset / datatype / count, width, height, point_step, row_step, is_bigendian, data): an rclpy message
(physdyn_ros.ros.cloud re-exports these functions for the nodes) or a rosbags message deserialized from a bag
(physdyn_ros.bag.pushes), so bag reports and datasets read clouds the same way on a machine without ROS.

Fields are read by name, as `sensor_msgs_py.point_cloud2.read_points_numpy` does: any cloud whose x, y and z
are FLOAT32 fields with count 1 is accepted, whatever its other fields, point_step, row padding, byte order or
organisation (height > 1). Anything else raises ValueError naming the problem, so a node can log it and carry on.
"""
from __future__ import annotations

import sys
from typing import Any

import numpy as np

XYZ = ("x", "y", "z")
#: sensor_msgs/msg/PointField.FLOAT32
FLOAT32 = 7


def _xyz_dtype(msg: Any) -> np.dtype:
    """A structured dtype picking x, y, z out of one point of `msg` (itemsize = point_step)."""
    names = [f.name for f in msg.fields]
    repeated = sorted({n for n in names if n in XYZ and names.count(n) > 1})
    if repeated:  # which one is the coordinate? Refuse rather than guess
        raise ValueError(f"cloud has the field {'/'.join(repeated)} more than once (fields: {', '.join(names)})")
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in XYZ if n not in fields]
    if missing:
        have = ", ".join(f"{f.name}({f.datatype})" for f in msg.fields) or "none"
        raise ValueError(f"cloud has no {'/'.join(missing)} field (fields: {have}); x, y, z float32 are required")
    order = ">" if msg.is_bigendian else "<"
    offsets = []
    for name in XYZ:
        f = fields[name]
        if f.datatype != FLOAT32:
            raise ValueError(f"cloud field {name!r} has datatype {f.datatype}, expected FLOAT32 ({FLOAT32})")
        if f.count != 1:
            raise ValueError(f"cloud field {name!r} has count {f.count}, expected 1")
        if f.offset + 4 > msg.point_step:
            raise ValueError(f"cloud field {name!r} at offset {f.offset} does not fit in point_step {msg.point_step}")
        offsets.append(int(f.offset))
    return np.dtype({"names": list(XYZ), "formats": [order + "f4"] * 3, "offsets": offsets,
                     "itemsize": int(msg.point_step)})


def cloud_size(msg: Any) -> int:
    """Number of points (width * height) the message claims."""
    return int(msg.width) * int(msg.height)


def _points_view(msg: Any) -> np.ndarray:
    """A zero-copy structured view (height, width) of the points, after checking the layout is consistent."""
    dtype = _xyz_dtype(msg)
    width, height, step, row = int(msg.width), int(msg.height), int(msg.point_step), int(msg.row_step)
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if width * height == 0:
        return np.zeros((height, width), dtype=dtype)
    if row < width * step:
        raise ValueError(f"cloud row_step {row} is smaller than width * point_step = {width * step}")
    if buf.size < row * height:
        raise ValueError(f"cloud data has {buf.size} bytes, expected row_step * height = {row * height}")
    # Strided view: handles row padding (row_step > width * point_step) without copying.
    return np.ndarray(shape=(height, width), dtype=dtype, buffer=buf, strides=(row, step))


def _float_view(msg: Any) -> tuple[np.ndarray, list[int]] | None:
    """Zero-copy (N, point_step / 4) float32 view of the points and the columns of x, y, z, for the common layout:
    native byte order, 4-byte aligned offsets and point_step, no row padding. None for any other layout."""
    dtype = _xyz_dtype(msg)  # validates the fields first
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    offsets = [dtype.fields[name][1] for name in XYZ]  # type: ignore[index]  # a structured dtype has fields
    if (bool(msg.is_bigendian) != (sys.byteorder == "big") or step % 4 or int(msg.row_step) != width * step
            or any(off % 4 for off in offsets)):
        return None
    n = width * height
    if len(msg.data) < n * step:
        return None  # _points_view names the problem
    buf = np.frombuffer(msg.data, dtype=np.float32, count=n * step // 4)
    return buf.reshape(n, step // 4), [off // 4 for off in offsets]


def cloud_to_xyz(msg: Any, skip_nans: bool = True, max_points: int | None = None,
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """The (N, 3) float32 x, y, z of a cloud, in the cloud's frame, native byte order.

    skip_nans drops points with a non-finite coordinate (organized clouds mark invalid pixels with NaN).
    max_points, when the cloud holds more points, reads only a uniform random subset of that many points (before
    dropping non-finite ones), so a 10-million-point cloud costs O(max_points) time and memory beyond the
    message itself. The common layout (native float32 x, y, z, no row padding) is read without a per-field copy:
    an x, y, z, 12-byte cloud is returned as a read-only view of the message's buffer when nothing is dropped.
    """
    n = cloud_size(msg)
    fast = _float_view(msg) if n else None
    idx = None
    if max_points is not None and n > max_points:
        rng = rng if rng is not None else np.random.default_rng()
        idx = np.sort(rng.choice(n, size=int(max_points), replace=False))
    if fast is not None:
        rows, cols = fast
        if idx is not None:
            rows = np.take(rows, idx, axis=0)
        if cols == [0, 1, 2] and rows.shape[1] == 3:
            out = rows.view()
            out.flags.writeable = False  # a view of the message's own buffer (when nothing is dropped below)
        else:
            out = rows[:, cols]
    else:
        view = _points_view(msg).reshape(-1)
        if idx is not None:
            view = view[idx]
        out = np.empty((view.shape[0], 3), dtype=np.float32)
        for i, name in enumerate(XYZ):
            out[:, i] = view[name]  # converts big-endian to native as it copies
    if skip_nans:
        ok = np.isfinite(out[:, 0]) & np.isfinite(out[:, 1]) & np.isfinite(out[:, 2])  # column-wise: ~15x faster
        if not ok.all():
            out = np.compress(ok, out, axis=0)
    return out
