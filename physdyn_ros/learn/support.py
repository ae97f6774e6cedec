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
"""Support-polygon descriptors of a cloud and the per-push quantities that decide tipping (numpy; the inputs of
the whole-push topple head, learn/topple.py).

Per object, from DESCRIPTOR_POINTS points of its cloud (frame C, z up, metres) and its centre of mass: the height
of the centre of mass over the support, the object's height, the area of the support polygon (the convex hull of
the lowest points) and how far it reaches from the centre of mass in each of SUPPORT_DIRECTIONS directions, the
cloud's second moments, and per direction the potential barrier of tilting the object to TOPPLE_ANGLE that way on
its own convex surface. Per push: the reach ahead of the push (friction at the base tips a sliding object forward
over that edge), the potential barrier of tipping over it, the kinetic energy, the tilt barrier ahead, and the
push's energy toward each direction against that direction's barrier. The per-object part runs once per object
(one 2-D hull); the per-push part is vectorised.

Why each part:
  * the tilt barriers: the support polygon of a round base (a lying can, a ball) is the band of its lowest points,
    which looks as wide as a flat face, but such an object rolls with no barrier; the centre of mass rising as
    the surface rolls on the table tells them apart;
  * the completed cloud: one depth camera misses the bottom on the table and the far side, so a view's lowest
    points and convex surface describe only its near side. Two facts fill them in: the object rests on the
    table with its centre of mass over the support (the centre of mass's foot on the table lies inside it), and
    most objects are mirror-symmetric about the vertical planes through their centre of mass along their
    principal axes (frame C's x axis is the cloud's principal axis): the mirror images of the seen side cover
    the hidden one. The descriptors are those of the points with their mirror images and that foot, read off the
    points without building the larger cloud;
  * the support band starts at the lowest point seen where that lies within SUPPORT_GAP_M of the table (the
    perception node removes the points just above the table plane), else the support is unseen and the foot
    alone stands for it;
  * the directional energies: an object that rolls across one axis (a dumbbell on its weights) rolls with the
    component of an oblique push across that axis while the rest slides along it, which the barrier straight
    ahead (the steep one of tipping over an end) hides;
  * the dense cloud: the tilt barriers and the support polygon are extremes of the points (the highest point
    toward a direction, the hull of the lowest), which a sparse sample such as the encoder's misses.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..conventions import GRAVITY, TOPPLE_ANGLE

#: Directions (in frame C, evenly spaced from +x) in which the support polygon's reach from the centre of mass
#: is measured.
SUPPORT_DIRECTIONS = 16
#: Tilt angles (rad, 0 to the topple angle) at which the centre of mass height is measured for the tilt barrier.
TILT_ANGLES = np.linspace(0.0, TOPPLE_ANGLE, 10)  # conventions: rad
#: Per-object descriptors: centre-of-mass height over the support, height, area of the support polygon, the
#: polygon's reach in each direction, the cloud's second moments about the centre of mass (x, y, z), the tilt
#: barrier toward each direction.
DESCRIPTOR_DIM = 3 + 2 * SUPPORT_DIRECTIONS + 3
#: Per-push quantities derived from the descriptors and the initial twist (push_quantities).
PUSH_DIM = 6 + 12 + 4 + 4
#: Points of the cloud the descriptors are computed on (a fixed subset of the cloud, points repeated where it has
#: fewer), more than the encoder's: see the module docstring.
DESCRIPTOR_POINTS = 1024
#: The lowest points within this band (the larger of an absolute and a relative tolerance) form the support.
BASE_BAND_M = 0.003
BASE_BAND_REL = 0.03
_INFLATE = 0.001  # m: a support seen as a line or a point becomes a thin polygon (a lying cylinder's edge)
#: A table below the lowest point by more than this fraction of the object's height over it, or above it by more
#: than TABLE_ABOVE_M, is not what the object rests on (a cloud given outside the table frame): the lowest point
#: stands in for it. A camera 70 deg above a ball (the steepest view in training) sees down to 0.33 of its height.
TABLE_GAP_REL = 0.5
TABLE_ABOVE_M = 0.005
#: The support band starts at the lowest point when that lies within this of the table (the perception node's
#: plane_distance of 5 mm, sensor noise, a sampled round bottom), else the support is unseen.
SUPPORT_GAP_M = 0.01


def _support_reach(base: np.ndarray, centre: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, float]:
    """Distance from `centre` (2,) along each unit direction (K, 2) to the edge of the convex hull of `base`
    (M, 2) (negative where the centre lies outside it), and the hull's area."""
    pts = base
    try:
        hull = ConvexHull(pts)
    except (QhullError, ValueError):  # a point or a line: inflate it
        offsets = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.float64) * _INFLATE
        pts = (base[:, None, :] + offsets[None]).reshape(-1, 2)
        hull = ConvexHull(pts)
    normals, offset = hull.equations[:, :2], hull.equations[:, 2]  # n . x + offset <= 0 inside
    slack = -(normals @ centre + offset)  # (E,) >= 0 inside
    along = normals @ dirs.T  # (E, K)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(along > 1e-9, slack[:, None] / along, np.inf)
    return t.min(axis=0), float(hull.volume)


def _directions() -> np.ndarray:
    angles = np.arange(SUPPORT_DIRECTIONS) * (2.0 * math.pi / SUPPORT_DIRECTIONS)
    return np.stack([np.cos(angles), np.sin(angles)], axis=1)


_DIRS = _directions()


def _tilt_down() -> np.ndarray:
    """(3, K * A) the table's downward normal in the object frame when the object is tilted by each of
    TILT_ANGLES toward each support direction (the side that goes down)."""
    dirs = _directions()
    s, c = np.sin(TILT_ANGLES), np.cos(TILT_ANGLES)
    return np.stack([np.outer(dirs[:, 0], s).ravel(), np.outer(dirs[:, 1], s).ravel(), -np.tile(c, len(dirs))])


_TILT_DOWN = _tilt_down()


def _tilt_heights(points: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(K, A): the height of `com` over the table when the object of `points` rests tilted by each of
    TILT_ANGLES toward each support direction on its own convex surface."""
    return ((points - com) @ _TILT_DOWN).max(axis=0).reshape(SUPPORT_DIRECTIONS, len(TILT_ANGLES))


def _barriers(height: np.ndarray) -> np.ndarray:
    return GRAVITY * (height.max(axis=1) - height[:, 0])


def resting_table(z: np.ndarray, table: float | None) -> float:
    """The height of the plane an object with point heights `z` rests on: `table` where it lies just below the
    lowest point (a view's lowest point may be cm above the table), else the lowest point."""
    z0, z1 = float(np.min(z)), float(np.max(z))
    if table is None or not np.isfinite(table):
        return z0
    table = float(table)
    return table if z0 - TABLE_GAP_REL * (z1 - table) <= table <= z0 + TABLE_ABOVE_M else z0


_FLIPS = np.array([[1.0, 1.0, 1.0], [-1.0, 1.0, 1.0], [1.0, -1.0, 1.0], [-1.0, -1.0, 1.0]])
# the support direction that the mirror images through x = c_x, y = c_y and both see as direction k
_K = np.arange(SUPPORT_DIRECTIONS)
_MIRRORED = np.stack([_K, (SUPPORT_DIRECTIONS // 2 - _K) % SUPPORT_DIRECTIONS, (-_K) % SUPPORT_DIRECTIONS,
                      (_K + SUPPORT_DIRECTIONS // 2) % SUPPORT_DIRECTIONS])
assert SUPPORT_DIRECTIONS % 2 == 0  # the directions must map onto each other under the mirrors


def _mirror_images(points: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(4N, 3): the points and their mirror images through the vertical planes x = com_x, y = com_y and both."""
    return (com + (points - com)[None] * _FLIPS[:, None]).reshape(-1, 3)


def _foot(com: np.ndarray, z: np.ndarray, table: float | None) -> np.ndarray:
    """(3,) the centre of mass's foot on the plane the object of point heights `z` rests on (resting_table)."""
    return np.array([com[0], com[1], resting_table(z, table)])


def support_descriptors(cloud: np.ndarray, com: np.ndarray, table: np.ndarray | None = None) -> np.ndarray:
    """Descriptors of clouds in frame C (z up, metres).

    Args:
        cloud: (B, N, 3) points of each object (DESCRIPTOR_POINTS of its cloud).
        com: (B, 3) centres of mass in the same frame.
        table: (B,) the height of the table plane in the same frame (None: each cloud's lowest point).

    Returns:
        (B, DESCRIPTOR_DIM) float64: the descriptors of each cloud completed with its mirror images through the
        vertical planes x = com_x, y = com_y and both, and its centre of mass's foot on the table
        (resting_table), computed from the points themselves (see the module docstring).
    """
    cloud = np.asarray(cloud, dtype=np.float64)
    com = np.asarray(com, dtype=np.float64).reshape(-1, 3)
    if cloud.ndim != 3 or cloud.shape[0] != com.shape[0] or cloud.shape[2] != 3:
        raise ValueError(f"clouds must be (B, N, 3) with one centre of mass each, got {cloud.shape}, {com.shape}")
    tables = np.full(len(cloud), np.nan) if table is None else np.asarray(table, dtype=np.float64).reshape(-1)
    if len(tables) != len(cloud):
        raise ValueError(f"table must hold one height per cloud ({len(cloud)}), got {len(tables)}")
    dirs = _directions()
    moments = 3 + SUPPORT_DIRECTIONS
    out = np.empty((len(cloud), DESCRIPTOR_DIM))
    for i, (pts, c) in enumerate(zip(cloud, com)):
        z = pts[:, 2]
        lowest = float(z.min())
        foot = _foot(c, z, tables[i])
        # the mirror images share the points' heights; the foot adds its own
        z0, top = min(lowest, float(foot[2])), max(float(z.max()), float(foot[2]))
        if lowest - foot[2] > SUPPORT_GAP_M:  # the support was not seen: the foot alone
            lowest = float(foot[2])
        height = top - z0
        band = lowest + max(BASE_BAND_M, BASE_BAND_REL * height)
        # the foot lies inside the support of an object at rest
        base = np.concatenate([_mirror_images(pts[z < band], c), foot[None]])
        reach, area = _support_reach(base[:, :2], c[:2], dirs)
        out[i, 0], out[i, 1], out[i, 2] = c[2] - z0, height, area
        out[i, 3:3 + SUPPORT_DIRECTIONS] = reach
        # the mirror images have the points' second moments, the foot its own
        second = np.mean((pts - c) ** 2, axis=0)
        out[i, moments:moments + 3] = (4 * len(pts) * second + (foot - c) ** 2) / (4 * len(pts) + 1)
        # an image's height tilted toward direction k is the points' toward the mirrored direction
        tilt = _tilt_heights(pts, c)[_MIRRORED].max(axis=0)
        out[i, moments + 3:] = _barriers(np.maximum(tilt, (c[2] - foot[2]) * np.cos(TILT_ANGLES)))
    return out


def sequence_descriptors(seq: Mapping[str, Any], com: np.ndarray) -> np.ndarray:
    """support_descriptors (B, DESCRIPTOR_DIM) of windows.make_windows' output (tensors or arrays): on its
    desc_cloud where it has one (made with desc_points = DESCRIPTOR_POINTS), else on the encoder's cloud; com
    (B, 3) in frame C."""
    cloud = seq["desc_cloud"] if "desc_cloud" in seq else seq["cloud"]
    return support_descriptors(np.asarray(cloud), com, np.asarray(seq["table"]))


def _reach_at(reach: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """The support reach (B, K) interpolated (circularly, linearly) at angles (B, A) in rad: (B, A)."""
    k = reach.shape[1]
    pos = np.mod(angle, 2.0 * math.pi) * (k / (2.0 * math.pi))
    lo = np.floor(pos)
    frac = pos - lo
    lo = lo.astype(np.int64) % k
    rows = np.arange(len(reach))[:, None]
    return (1.0 - frac) * reach[rows, lo] + frac * reach[rows, (lo + 1) % k]


_QUARTERS = np.array([0.0, math.pi, 0.5 * math.pi, -0.5 * math.pi])  # ahead, behind, left, right of the push


def push_quantities(desc: np.ndarray, vel: np.ndarray, angvel: np.ndarray) -> np.ndarray:
    """What decides tipping, per push.

    Args:
        desc: (B, DESCRIPTOR_DIM) support_descriptors of the pushed objects.
        vel, angvel: (B, 3) the initial twist in frame C (m/s, rad/s).

    Returns:
        (B, PUSH_DIM) float64: the twist (6); speed, tipping and yaw rates, the support's reach ahead of /
        behind / beside the push and its minimum, the potential barrier of tipping over the front edge and the
        kinetic energy (both per unit mass), their log ratio, the friction lever h / reach ahead, the rate at
        which sliding tips the object about that edge (12); the tilt barrier ahead of the push and its minimum
        over directions (J/kg) and the log ratio of the kinetic energy to each (4); toward the direction k where
        the push's kinetic energy toward k, 0.5 max(v . d_k, 0)^2, is largest against the tilt barrier that way:
        their log ratio, that barrier, that energy, and the cosine between k and the push (4).
    """
    desc = np.asarray(desc, dtype=np.float64)
    if desc.ndim != 2 or desc.shape[1] != DESCRIPTOR_DIM:
        raise ValueError(f"descriptors must be (B, {DESCRIPTOR_DIM}) (support_descriptors), got {desc.shape}")
    vel = np.asarray(vel, dtype=np.float64).reshape(-1, 3)
    angvel = np.asarray(angvel, dtype=np.float64).reshape(-1, 3)
    h = desc[:, 0]
    reach = desc[:, 3:3 + SUPPORT_DIRECTIONS]
    gyration2 = desc[:, 3 + SUPPORT_DIRECTIONS:6 + SUPPORT_DIRECTIONS].sum(axis=1)
    tilt = desc[:, 6 + SUPPORT_DIRECTIONS:]
    speed = np.linalg.norm(vel[:, :2], axis=1)
    heading = np.arctan2(vel[:, 1], vel[:, 0])
    angles = heading[:, None] + _QUARTERS
    # reach and tilt barrier in one interpolation (a per-call cost at batch 1): rows B.. are the tilt's
    at = _reach_at(np.concatenate([reach, tilt]), np.concatenate([angles, angles]))
    ahead, back, left, right = at[:len(reach)].T
    front, side = ahead, np.minimum(left, right)
    lever = np.maximum(front, 0.0)
    barrier = GRAVITY * (np.sqrt(h * h + lever * lever) - h)
    tip_rate = np.linalg.norm(angvel[:, :2], axis=1)
    kinetic = 0.5 * speed ** 2 + 0.5 * gyration2 * tip_rate ** 2
    ratio = np.log((kinetic + 1e-6) / (barrier + 1e-6))
    slide_tip = speed * h / (h * h + lever * lever + 1e-6)
    columns = [speed, tip_rate, np.abs(angvel[:, 2]), front, back, side, reach.min(axis=1), barrier, kinetic, ratio,
               h / (lever + 1e-3), slide_tip]
    tilt_ahead, tilt_min = at[len(reach):, 0], tilt.min(axis=1)
    columns += [tilt_ahead, tilt_min, np.log((kinetic + 1e-6) / (tilt_ahead + 1e-6)),
                np.log((kinetic + 1e-6) / (tilt_min + 1e-6))]
    # the push's energy toward each direction against that direction's barrier (an oblique push rolls a
    # round-based object across its axis with the push's component that way)
    along = np.maximum(vel[:, :2] @ _DIRS.T, 0.0)  # (B, K) m/s toward each direction
    toward = 0.5 * along ** 2
    ratios = np.log((toward + 1e-6) / (tilt + 1e-6))
    best = np.argmax(ratios, axis=1)
    rows = np.arange(len(best))
    cosine = along[rows, best] / np.maximum(speed, 1e-9)
    columns += [ratios[rows, best], tilt[rows, best], toward[rows, best], np.where(speed > 0.0, cosine, 0.0)]
    return np.concatenate([vel, angvel, np.stack(columns, axis=1)], axis=1)
