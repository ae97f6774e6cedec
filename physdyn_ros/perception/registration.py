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
"""Rigid registration of an object's points to its model: point-to-plane ICP (numpy and scipy; no ROS, no open3d).

An `ObjectModel` holds an object's surface in its own frame (origin at the centre-of-mass estimate, axes those of
the table frame when the model was captured), a k-d tree over it and a normal per point. `register` finds the
pose (R, t) that maps the model onto points observed in the table frame, starting from a guess: Gauss-Newton on
point-to-plane distances, with a small damping so that directions the view does not constrain (the spin of a
cylinder about its axis, a lone flat face) stay at the guess instead of drifting. The correspondence distance
halves from `max_distance` down to `min_distance` over the iterations: a coarse guess (the first frame of a push) is
pulled in, and the final iterations ignore stray points (a hand, a neighbour's edge).

Why not open3d: its registration of ~300 points costs about as much in conversions and thread start-up as
the whole fit here, and its import takes a second; this loop is a few hundred microseconds per object.

`ObjectModel.grow` adds observed points that lie off the model (faces the reference view did not see): after a
90 deg turn the camera sees other faces than at capture, and a model of the first view only would drag the fit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

#: Neighbours of a model point whose plane gives its normal.
NORMAL_NEIGHBORS = 10
#: m: observed points this close to the model are its inliers (the final correspondence distance of `register`).
INLIER_DISTANCE = 0.006


def estimate_normals(points: np.ndarray, k: int = NORMAL_NEIGHBORS, tree: cKDTree | None = None) -> np.ndarray:
    """(N, 3) unit normals: the smallest principal axis of each point's k nearest neighbours (sign arbitrary)."""
    if len(points) < 3:
        return np.tile([0.0, 0.0, 1.0], (len(points), 1))
    tree = tree if tree is not None else cKDTree(points)
    _, idx = tree.query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def rotvec_matrix(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues; scipy's Rotation costs tens of microseconds per call)."""
    angle = float(np.sqrt(v @ v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


@dataclass
class Fit:
    """A registration: model frame -> table frame, and how well the points agree with the model."""

    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,) m: where the model's origin (the centre-of-mass estimate) is
    rmse: float  # m, point-to-plane residual of the inliers
    inliers: float  # share of the observed points within min_distance of the model
    iterations: int


class ObjectModel:
    """An object's surface in its own frame (see the module docstring)."""

    def __init__(self, points: np.ndarray, voxel: float = 0.003, max_points: int = 3000) -> None:
        self.voxel, self.max_points = float(voxel), int(max_points)
        # the voxel grid stays where it was when the origin moves (move_origin): a grid moved by a fraction of a
        # voxel would put neighbours in one cell at the next thinning and drop them for good
        self._grid = np.zeros(3)
        pts = np.asarray(points, dtype=np.float64)
        self.points = pts[self._thin(pts)]
        # clouds that had a point within 1.5 voxels of each model point (observe): a surface seen at rest gains
        # one a cloud, a depth camera's mixed pixels, scattered along their rays, hardly any
        self.hits = np.zeros(len(self.points), dtype=np.int64)
        self._pending: list[np.ndarray] = []
        self._index()

    def _thin(self, pts: np.ndarray) -> np.ndarray:
        """Indices of one point per voxel (the first), at most max_points (an even subset)."""
        keep = np.arange(len(pts))
        if len(pts) == 0 or self.voxel <= 0:
            return keep
        keys = np.floor((pts + self._grid) / self.voxel).astype(np.int64)
        _, first = np.unique(keys, axis=0, return_index=True)
        keep = np.sort(first)
        if len(keep) > self.max_points:
            keep = keep[np.linspace(0, len(keep) - 1, self.max_points).astype(int)]
        return keep

    def observe(self, observed_in_model: np.ndarray) -> None:
        """Count a cloud's points (model frame, at a pose that fits) against the model points they lie near."""
        if not len(observed_in_model) or not len(self.points):
            return
        d, _ = cKDTree(observed_in_model).query(self.points, distance_upper_bound=1.5 * self.voxel)
        self.hits[np.isfinite(d)] += 1

    def _index(self) -> None:
        self._tree()
        self.normals = estimate_normals(self.points, tree=self.tree)

    def _tree(self) -> None:
        self.tree = cKDTree(self.points)
        self.size = max(0.01, float(np.sqrt(np.mean(np.sum(self.points ** 2, axis=1)))))  # m, RMS radius

    def move_origin(self, offset: np.ndarray) -> None:
        """Put the model's origin at `offset` (model frame): its points move by -offset (normals unchanged)."""
        offset = np.asarray(offset, dtype=np.float64)
        self._grid = self._grid + offset
        self.points = self.points - offset
        self._pending = [p - offset for p in self._pending]
        self._tree()

    def grow(self, observed_in_model: np.ndarray, reach: float = 0.02) -> int:
        """Add points (model frame) that lie farther than one voxel from the model but within `reach` of it
        (new faces next to known ones; farther ones are more likely another object or a hand). The k-d tree and
        normals are rebuilt once the new points reach a tenth of the model. Returns the points added."""
        if len(self.points) >= self.max_points or not len(observed_in_model):
            return 0
        d, _ = self.tree.query(observed_in_model, distance_upper_bound=reach)
        new = observed_in_model[(d > 1.5 * self.voxel) & np.isfinite(d)]
        if len(new):
            self._pending.append(new)
        waiting = sum(len(p) for p in self._pending)
        if waiting >= max(20, 0.1 * len(self.points)):
            pts = np.vstack([self.points] + self._pending)
            hits = np.concatenate([self.hits, np.zeros(waiting, dtype=np.int64)])
            keep = self._thin(pts)
            self.points, self.hits = pts[keep], hits[keep]
            self._pending = []
            self._index()
        return len(new)


def register(points: np.ndarray, model: ObjectModel, rotation: np.ndarray, translation: np.ndarray, *,
             max_distance: float = 0.03, min_distance: float = INLIER_DISTANCE, iterations: int = 10,
             damping: float = 1e-4, degenerate: float = 0.08, tilt: bool = True) -> Fit:
    """Pose of `model` that best explains `points` (N, 3, table frame), from the guess (rotation, translation).

    degenerate: directions whose curvature is below this share of the largest are not moved.
    tilt False: yaw about the table's z axis and translation only (4 degrees of freedom), for objects known to
    stay upright. Never raises for bad data: a fit without correspondences returns the guess with inliers 0.
    """
    q = np.asarray(points, dtype=np.float64)
    rot, t = np.array(rotation, dtype=np.float64), np.array(translation, dtype=np.float64)
    free = np.arange(6) if tilt else np.array([2, 3, 4, 5])  # unknowns: rotation vector (3), translation (3)
    # rotation columns in m (times the object's size): comparable with the translation columns, so that one
    # threshold finds the directions the view leaves free (a cylinder's spin, a face's in-plane slide)
    unit = np.where(free < 3, 1.0 / model.size, 1.0)
    n_it, rmse, gate = 0, float("inf"), float(max_distance)
    for k in range(iterations):
        n_it = k + 1
        y = (q - t) @ rot  # the points in the model frame: R^T (q - t)
        d, idx = model.tree.query(y, distance_upper_bound=gate)
        ok = d < gate
        if ok.sum() < 6:
            break
        yo, p, n = y[ok], model.points[idx[ok]], model.normals[idx[ok]]
        # model-frame residuals n . (y - p) for a small model-frame motion of the points (y -> y + w x y + v);
        # moving the points by (w, v) in the model frame is moving the model by its inverse
        r = ((yo - p) * n).sum(axis=1)
        jac = np.empty((len(r), 6))
        jac[:, 0] = yo[:, 1] * n[:, 2] - yo[:, 2] * n[:, 1]  # y x n, written out: np.cross costs 10x more here
        jac[:, 1] = yo[:, 2] * n[:, 0] - yo[:, 0] * n[:, 2]
        jac[:, 2] = yo[:, 0] * n[:, 1] - yo[:, 1] * n[:, 0]
        jac[:, 3:] = n
        jn = (jac[:, free] if len(free) < 6 else jac) * unit
        # Huber-like weights: a few far-off points (an occluding hand) do not dominate
        scale = max(1.5e-3, 1.25 * float(np.abs(r).mean()))
        w = 1.0 / np.maximum(1.0, np.abs(r) / (2.0 * scale))
        jw = jn * w[:, None]
        a = jw.T @ jn
        b = -(jw.T @ r)
        vals, vecs = np.linalg.eigh(a)
        keep = vals > max(degenerate * float(vals[-1]), 1e-12)
        # a truncated solve: no step along unconstrained directions (they stay at the guess, instead of drifting
        # with the noise from cloud to cloud); a little damping on the others
        x = vecs[:, keep] @ ((vecs[:, keep].T @ b) / (vals[keep] + damping * len(r)))
        step = np.zeros(6)
        step[free] = x * unit
        # y' = dr y + v = R'^T (q - t')  =>  R' = R dr^T, t' = t - R' v
        rot = rot @ rotvec_matrix(step[:3]).T
        t = t - rot @ step[3:]
        small = float(step[:3] @ step[:3]) < 1e-6 and float(step[3:] @ step[3:]) < 1e-8  # 0.06 deg, 0.1 mm
        if small and gate <= min_distance:
            break
        gate = max(float(min_distance), 0.5 * gate)  # coarse to fine: pull a far guess in, then drop strays
    # orthonormalise (the product of many small rotations drifts by rounding)
    u, _, vt = np.linalg.svd(rot)
    rot = u @ vt
    y = (q - t) @ rot
    d, idx = model.tree.query(y, distance_upper_bound=min_distance)
    ok = np.isfinite(d)
    if ok.any():
        r = np.einsum("ij,ij->i", model.normals[idx[ok]], y[ok] - model.points[idx[ok]])
        rmse = float(np.sqrt(np.mean(r * r)))
    return Fit(rot, t, rmse, float(ok.mean()) if len(q) else 0.0, n_it)
