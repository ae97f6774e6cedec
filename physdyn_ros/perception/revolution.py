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
"""The vertical axis of a surface of revolution seen from one side (numpy and scipy; no ROS).

One camera sees one side of a bottle, a can, a cup or a ball: the view's points, and the solid under them, lie
towards the camera, and a top face smaller than the body (a bottle's cap) spans too little of the view to stand
for the footprint (pose_tracking.footprint_com). Their horizontal sections are circles about one vertical axis,
and the arc each section shows fixes its circle's centre: that axis holds the centre of mass of a uniform solid of
revolution, whatever side the camera sees.

`revolution_axis` cuts the view into BANDS height bands and fits each but the top one (a cap, a rim, a flat top)
with circles about one centre whose radius changes linearly with height (a band of a ball narrows), by least
squares with the points farther than 3 robust sigmas from it left out. The view counts as a surface of revolution
only when at least half the fitted bands (two at least) lie on their circles up to sensor noise, over arcs that
span at least MIN_ARC with no gap wider than MAX_GAP, and their centres lie within AGREEMENT of each other. The
test on noise: the residuals, smoothed along the arc by a running median, stay within SYSTEMATIC. Sensor noise
averages out of them, while the flat faces of a box or a prism, or a rounded box's corners, leave a systematic
pattern that does not. Everything else (a box, a wedge) returns None, and the caller keeps its own estimate. A
handle counts as outliers while it holds under a fifth of a band's points.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy.ndimage import median_filter
from scipy.optimize import least_squares

__all__ = ["revolution_axis"]

#: Height bands between the lowest point 5 mm above the table and the top; the top one is not fitted.
BANDS = 6
BASE_GAP = 0.005
#: Points a band needs to be fitted, and that must remain after the outliers left out.
MIN_BAND_POINTS = 30
MIN_INLIERS = 20
#: Outliers: farther from the circle than OUTLIER_SIGMAS robust sigmas, and at least OUTLIER_FLOOR (m).
OUTLIER_SIGMAS, OUTLIER_FLOOR = 3.0, 0.0015
#: Share of a band's points that must lie on its circle (the rest: mixed pixels, a handle, a label's edge).
MIN_INLIER_SHARE = 0.8
#: Systematic residual allowed: m, plus this share of the radius (95th percentile of the smoothed residuals).
SYSTEMATIC = (0.0007, 0.003)
#: Arc a band must span about its centre (a shorter one fixes the centre poorly), and the widest gap within it.
MIN_ARC, MAX_GAP = math.radians(90.0), math.radians(45.0)
#: A radius above RADIUS_SPAN x the band's extent (its bounding box's diagonal) plus RADIUS_SLACK (m) is a nearly
#: flat face, not an arc.
RADIUS_SPAN, RADIUS_SLACK = 0.75, 0.01
#: Band centres must lie within this (m) of each other.
AGREEMENT = 0.004


def _circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (2,) and radius of the algebraic least-squares circle through xy (N, 2)."""
    a = np.column_stack([xy, np.ones(len(xy))])
    sol = np.linalg.lstsq(a, (xy * xy).sum(axis=1), rcond=None)[0]
    centre = 0.5 * sol[:2]
    return centre, math.sqrt(max(float(sol[2] + centre @ centre), 0.0))


def _tapered(xy: np.ndarray, dz: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Centre (2,), radius at dz = 0 and its slope of the section circles r(dz) = r0 + r1 dz nearest the points
    xy (N, 2) at heights dz (N,) (a band of a ball or a shoulder narrows with height), by geometric least squares
    from the algebraic circle."""
    centre, radius = _circle(xy)

    def residual(p: np.ndarray) -> np.ndarray:
        return np.hypot(xy[:, 0] - p[0], xy[:, 1] - p[1]) - (p[2] + p[3] * dz)

    p = least_squares(residual, np.array([centre[0], centre[1], radius, 0.0]), method="lm").x
    return p[:2], float(p[2]), float(p[3])


def _band_centre(xy: np.ndarray, dz: np.ndarray) -> Optional[np.ndarray]:
    """The axis of the circles a band's points (N, 2) at heights dz (N; from the band's middle) lie on, or None
    when they do not lie on such circles."""
    keep = np.ones(len(xy), dtype=bool)
    try:
        for _ in range(3):
            centre, radius, slope = _tapered(xy[keep], dz[keep])
            res = np.linalg.norm(xy - centre, axis=1) - (radius + slope * dz)
            inl = res[keep]
            sigma = 1.4826 * float(np.median(np.abs(inl - np.median(inl))))
            keep = np.abs(res) < max(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR)
            if keep.sum() < MIN_INLIERS:
                return None
        if keep.mean() < MIN_INLIER_SHARE:
            return None
        centre, radius, slope = _tapered(xy[keep], dz[keep])
    except (ValueError, np.linalg.LinAlgError):  # collinear or coincident points: no circle
        return None
    d = xy[keep] - centre
    angle = np.arctan2(d[:, 1], d[:, 0])
    order = np.argsort(angle)
    gaps = np.diff(np.concatenate([angle[order], angle[order][:1] + 2.0 * math.pi]))
    widest = int(np.argmax(gaps))
    # along the arc from one end to the other (not from -pi: an arc across -pi would be joined at its ends)
    order, inner = np.roll(order, -(widest + 1)), np.delete(gaps, widest)
    res = (np.linalg.norm(d, axis=1) - (radius + slope * dz[keep]))[order]
    smooth = median_filter(res, size=max(9, len(res) // 15) | 1, mode="nearest")
    extent = float(np.hypot(*np.ptp(xy, axis=0)))
    if (float(np.percentile(np.abs(smooth), 95)) > SYSTEMATIC[0] + SYSTEMATIC[1] * radius
            or 2.0 * math.pi - float(gaps[widest]) < MIN_ARC or float(inner.max(initial=0.0)) > MAX_GAP
            or radius > RADIUS_SPAN * extent + RADIUS_SLACK):
        return None
    return centre


def revolution_axis(points: np.ndarray, table_height: float = 0.0) -> Optional[np.ndarray]:
    """x-y (2,) of the vertical axis about which a view's points (N, 3, table frame, m) form a surface of
    revolution, or None when they do not (module docstring)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        return None
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < MIN_BAND_POINTS * 2:
        return None
    z = pts[:, 2] - table_height
    low, high = max(float(z.min()), BASE_GAP), float(np.percentile(z, 99.5))
    if high - low < 4.0 * BASE_GAP:
        return None
    edges = np.linspace(low, high, BANDS + 1)
    centres, weights, fitted = [], [], 0
    for k in range(BANDS - 1):
        rows = (z >= edges[k]) & (z < edges[k + 1])
        if rows.sum() < MIN_BAND_POINTS:
            continue
        fitted += 1
        centre = _band_centre(pts[rows, :2], z[rows] - 0.5 * (edges[k] + edges[k + 1]))
        if centre is not None:
            centres.append(centre)
            weights.append(int(rows.sum()))
    if len(centres) < 2 or len(centres) < 0.5 * fitted:
        return None
    stacked = np.array(centres)
    if np.linalg.norm(stacked[:, None] - stacked[None], axis=2).max() > AGREEMENT:
        return None
    return np.average(stacked, axis=0, weights=weights)
