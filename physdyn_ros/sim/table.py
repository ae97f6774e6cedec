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
"""What the sim node accepts of the objects it spawns and the pushes it applies, checked without ROS.

Each check raises ValueError with a reason that names the bad value; the node answers its service with it.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..geometry import quat_to_matrix

#: m, the size range of a spawned object along each axis: what a robot pushes on a table (scale 1000 made a
#: box of 494,000 t).
MIN_OBJECT_SIZE, MAX_OBJECT_SIZE = 0.01, 1.0
#: m: objects are spawned at most this far from the table frame's origin along x and y.
MAX_SPAWN_DISTANCE = 10.0
#: m: a push's contact point may lie at most this far outside the object's hull (a pusher's tip, the hull's
#: approximation of a curved surface).
MAX_CONTACT_GAP = 0.02
#: Keys of an `objects` parameter entry ("id=can category=cylinder x=0.25 ..."); id is required.
OBJECT_KEYS = ("id", "category", "shape_seed", "mesh_path", "scale", "x", "y", "yaw", "friction")


def parse_object_entry(entry: str, defaults: dict) -> dict:
    """One `objects` parameter entry, "id=NAME [category=C] [shape_seed=N] [mesh_path=P] [scale=SX,SY,SZ] [x=X]
    [y=Y] [yaw=YAW] [friction=MU]", as keyword values (missing keys from `defaults`); ValueError naming the entry."""
    out = dict(defaults)
    for token in entry.split():
        key, sep, value = token.partition("=")
        if not sep or key not in OBJECT_KEYS:
            keys = ", ".join(k + "=" for k in OBJECT_KEYS)
            raise ValueError(f"objects entry {entry!r}: {token!r} is not one of {keys}")
        try:
            out[key] = (value if key in ("id", "category", "mesh_path") else
                        int(value) if key == "shape_seed" else
                        [float(v) for v in value.split(",")] if key == "scale" else float(value))
        except ValueError:
            raise ValueError(f"objects entry {entry!r}: {key}={value!r} is not a number") from None
    if not out.get("id"):
        raise ValueError(f"objects entry {entry!r} has no id=NAME")
    return out


def check_spawn(scale: Sequence[float], spawn_pose: Sequence[float], friction: float
                ) -> tuple[np.ndarray, tuple[float, float, float]]:
    """(scale (3,), (x, y, yaw)) of a spawn request, checked: positive scale, a finite pose on the table, friction
    in [0, 10]."""
    s = np.asarray(scale, dtype=np.float64).reshape(-1)
    if s.size != 3 or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"scale must be 3 positive numbers, got {s.tolist()}")
    x, y, yaw = (float(v) for v in spawn_pose)
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError("spawn pose must be finite")
    if max(abs(x), abs(y)) > MAX_SPAWN_DISTANCE:
        raise ValueError(f"spawn position ({x:g}, {y:g}) m is more than {MAX_SPAWN_DISTANCE:g} m from the table "
                         "frame's origin")
    if not 0.0 <= friction <= 10.0:
        raise ValueError(f"friction must be in [0, 10], got {friction}")
    return s, (x, y, yaw)


def check_size(shape: Any, scale: np.ndarray) -> None:
    """ValueError unless the scaled shape measures MIN_OBJECT_SIZE-MAX_OBJECT_SIZE along each axis."""
    size = np.asarray(shape.extents, dtype=np.float64) * scale
    if size.max() > MAX_OBJECT_SIZE or size.min() < MIN_OBJECT_SIZE:
        raise ValueError(f"scale {scale.tolist()} makes {shape.name} {size[0]:.3g} x {size[1]:.3g} x "
                         f"{size[2]:.3g} m; a tabletop object must measure {MIN_OBJECT_SIZE:g}-"
                         f"{MAX_OBJECT_SIZE:g} m along each axis")


def surface_gap(sim: Any, object_id: str, point: np.ndarray) -> float:
    """How far (m) `point` (world frame) lies outside the simulator object's convex hull; 0 on or inside it. The
    largest signed distance to the hull's face planes: exact off a face, a lower bound off an edge."""
    from scipy.spatial import ConvexHull

    b = sim.get(object_id)
    pos, q, _, _ = sim.state(object_id)
    local = quat_to_matrix(q).T @ (np.asarray(point, dtype=np.float64) - pos)
    hull = ConvexHull(np.asarray(b.shape.hull()[0], dtype=np.float64) * b.scale)
    return max(0.0, float(np.max(hull.equations[:, :3] @ local + hull.equations[:, 3])))


def object_at(sim: Any, point: np.ndarray, fallback: str) -> str:
    """The id of the object whose convex hull lies nearest `point` (world frame): the one a push there touches.
    `fallback` when the point is unset (all zero: the centre of mass) or the world holds at most one object."""
    point = np.asarray(point, dtype=np.float64)
    if len(sim.ids) <= 1 or not np.any(point) or not np.all(np.isfinite(point)):
        return fallback
    return min(sim.ids, key=lambda oid: surface_gap(sim, oid, point))
