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
"""Rotational symmetry of an observed cloud about its up axis: which yaw goals the object can show.

An upright cylinder, bottle or ball looks the same at every yaw, and a square box at every quarter turn: a yaw
goal beyond what the cloud shows can neither be planned for (the model sees no difference) nor checked (a
tracker cannot measure it). `yaw_symmetry(cloud)` returns the order k of the rotations about the vertical axis
that map the cloud onto itself: NONE (1), 2..8 (k-fold: the yaw matters modulo 360/k deg) or CONTINUOUS (0: the
yaw does not matter). Goal.yaw_symmetry carries it to the planner's cost and to the closed loop's goal errors, so
that a plan, its check and a bench's success use the same rule (types.fold_yaw).

A rotation by t about the axis maps the cloud onto itself when two tests pass:
* the outline: per height band (BANDS of the cloud's height), the support function h(phi) (how far the points
  reach in direction phi, the mean of the TOP_POINTS farthest) of the rotated cloud differs from the cloud's
  own by at most OUTLINE_TOLERANCE + OUTLINE_SLACK x the horizontal radius at the OUTLINE_QUANTILE of
  (band, phi); a mean of the farthest points, not their maximum, keeps 2 mm of sensor noise under ~2 mm;
* the surface: split the points into two random halves A and B; at most MAX_MISMATCH of the rotated A lie
  farther from B than MATCH_FACTOR x the MATCH_QUANTILE distance of the unrotated A to B (plus MATCH_SLACK of
  the radius): a feature inside the outline (a hole, a notch) is caught here. This test alone is too lenient
  for sparse clouds (1024 points put ~1 cm between neighbours on a 30 cm box), hence the outline test.
The axis passes through the area centroid of the cloud's horizontal hull, which every rotation symmetry of the
object keeps fixed, whatever the sampling density. Continuous symmetry: CONTINUOUS_ANGLES all pass (180/k deg
for every k of ORDERS, where a k-fold object differs most from itself, and 17 deg); else the largest k of
ORDERS whose multiples of 360/k up to a half turn all pass. A partial
view (one side of the object) does not map onto itself under a rotation, so it is reported as not symmetric:
the yaw goal is kept, the cautious answer. test_symmetry.py holds the shapes it was tuned on.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from ..perception.scene import hull_centroid, random_rows

__all__ = ["CONTINUOUS", "NONE", "symmetry_note", "yaw_symmetry"]

#: yaw_symmetry's answer for a cloud that looks the same at every yaw.
CONTINUOUS = 0
#: ... and for one that looks different at every yaw.
NONE = 1
#: The discrete orders tested (a k-fold object looks the same after 360/k deg).
ORDERS = tuple(range(2, 9))
#: Rotations (rad) that must all pass for continuous symmetry: half the period of every order tested (where a
#: k-fold object differs most from itself: 90 deg for a box, 60 deg for a triangle) and 17 deg (between them).
CONTINUOUS_ANGLES = tuple(math.pi / k for k in ORDERS) + (math.radians(17.0),)
#: Points used (a random subset of larger clouds).
MAX_POINTS = 1024
#: Outline test: height bands (those with fewer than MIN_BAND_POINTS are skipped), directions, the farthest points
#: averaged per direction ...
BANDS, MIN_BAND_POINTS, DIRECTIONS, TOP_POINTS = 4, 12, 72, 3
#: ... and the tolerance: m, plus a share of the horizontal radius, at this quantile of (band, direction).
OUTLINE_TOLERANCE, OUTLINE_SLACK, OUTLINE_QUANTILE = 0.0025, 0.02, 0.9
#: Distance threshold: MATCH_FACTOR x the MATCH_QUANTILE of the unrotated half-to-half distances ...
MATCH_QUANTILE, MATCH_FACTOR = 0.95, 1.5
#: ... plus this share of the cloud's horizontal radius.
MATCH_SLACK = 0.01
#: Share of the rotated points that may lie off the cloud for a rotation to pass.
MAX_MISMATCH = 0.03


def _axis(points: np.ndarray) -> np.ndarray:
    """(2,) area centroid of the hull of the points' horizontal projection (the mean for a degenerate hull)."""
    hull = hull_centroid(points[:, :2], min_area=1e-12)
    return points[:, :2].mean(axis=0) if hull is None else hull[0]


def _rotate(points: np.ndarray, centre: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    out = points.copy()
    d = points[:, :2] - centre
    out[:, 0] = centre[0] + c * d[:, 0] - s * d[:, 1]
    out[:, 1] = centre[1] + s * d[:, 0] + c * d[:, 1]
    return out


def _outline(points: np.ndarray, centre: np.ndarray, bands: list[np.ndarray], units: np.ndarray) -> np.ndarray:
    """(bands, directions) support function of the points about `centre`: per band (index arrays) and direction,
    the mean projection of the TOP_POINTS farthest points."""
    out = []
    for idx in bands:
        proj = (points[idx, :2] - centre) @ units.T  # (n, D)
        top = np.partition(proj, len(idx) - TOP_POINTS, axis=0)[-TOP_POINTS:]
        out.append(top.mean(axis=0))
    return np.array(out)


def yaw_symmetry(cloud: np.ndarray, seed: int = 0) -> int:
    """Order of the cloud's rotational symmetry about the vertical axis (table frame z): CONTINUOUS (0), NONE (1)
    or k in ORDERS (the largest that passes). Deterministic for a seed; a few milliseconds for 1024 points."""
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 16 or not np.all(np.isfinite(pts)):
        return NONE
    rng = np.random.default_rng(seed)
    pts = random_rows(pts, MAX_POINTS, rng)
    order = rng.permutation(len(pts))
    a, b = pts[order[::2]], pts[order[1::2]]
    centre = _axis(pts)
    radius = float(np.linalg.norm(pts[:, :2] - centre, axis=1).max())
    if radius <= 0:
        return NONE
    z = pts[:, 2]
    edges = np.linspace(z.min(), z.max(), BANDS + 1)
    band = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, BANDS - 1)
    bands = [np.flatnonzero(band == i) for i in range(BANDS)]
    bands = [idx for idx in bands if len(idx) >= max(MIN_BAND_POINTS, TOP_POINTS)]
    phi = np.arange(DIRECTIONS) * (2.0 * math.pi / DIRECTIONS)
    units = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    outline = _outline(pts, centre, bands, units)
    outline_tol = OUTLINE_TOLERANCE + OUTLINE_SLACK * radius
    tree = cKDTree(b)
    base = tree.query(a)[0]
    threshold = MATCH_FACTOR * float(np.quantile(base, MATCH_QUANTILE)) + MATCH_SLACK * radius

    seen: dict[float, bool] = {}

    def passes(angle: float) -> bool:
        key = round(angle, 9)
        if key not in seen:
            moved = _outline(_rotate(pts, centre, angle), centre, bands, units)
            ok = float(np.quantile(np.abs(moved - outline), OUTLINE_QUANTILE)) <= outline_tol
            seen[key] = ok and float(np.mean(tree.query(_rotate(a, centre, angle))[0] > threshold)) <= MAX_MISMATCH
        return seen[key]

    if all(passes(t) for t in CONTINUOUS_ANGLES):
        return CONTINUOUS
    # k-fold: every multiple of 360/k up to a half turn passes (the tolerance is not transitive: a stretched
    # 12-gon passes 45 deg, not 90 deg)
    for k in sorted(ORDERS, reverse=True):
        if all(passes(2.0 * math.pi * j / k) for j in range(1, k // 2 + 1)):
            return k
    return NONE


def symmetry_note(order: int | None) -> str:
    """What the symmetry does to a yaw goal, for a plan's message ("" when nothing)."""
    if order == CONTINUOUS:
        return "yaw goal ignored: the cloud is rotationally symmetric about its up axis"
    if order is not None and order >= 2:
        return (f"yaw goal taken modulo {360.0 / order:.3g} deg: the cloud is {order}-fold symmetric about its up "
                "axis")
    return ""
