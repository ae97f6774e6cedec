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
pulled in, and the final iterations ignore stray points (a hand, a neighbour's edge). A translation left free
that way (a slide along a long bar seen from its side: its top and side faces hold it only through the grazing
end face) is then searched along, for the shift that puts the view's ends on the model's (`_slide_along`).

Why not open3d: its registration of ~300 points costs about as much in conversions and thread start-up as
the whole fit here, and its import takes a second; this loop is a few hundred microseconds per object (the slide
search about 0.7 ms more where a view leaves a slide free).

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

    def observe(self, observed_in_model: np.ndarray, upto: int | None = None) -> None:
        """Count a cloud's points (model frame, at a pose that fits) against the model points they lie near; with
        `upto`, only the model points not yet counted that often (a caller that asks only whether a point was seen
        `upto` times: at rest, every point in view reaches it within a few clouds and is not queried again)."""
        if not len(observed_in_model) or not len(self.points):
            return
        todo = np.flatnonzero(self.hits < upto) if upto is not None else np.arange(len(self.points))
        if not len(todo):
            return
        d, _ = cKDTree(observed_in_model).query(self.points[todo], distance_upper_bound=1.5 * self.voxel)
        self.hits[todo[np.isfinite(d)]] += 1

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


#: m: the search along a free translation (_slide_along) steps this finely; shifts that leave at most SLIDE_SLACK
#: (share) more of the points off the model than the best one count as fitting (sensor noise, mixed pixels).
SLIDE_STEP = 0.002
SLIDE_SLACK = 0.01
#: m: a run of fitting shifts at most this much longer than the view's own slack (2 near) is pinned at both ends
#: (the slack's few points of each end blur its edges by millimetres)
SLIDE_PINNED = 0.008


def _free_translations(vecs: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(k, 3) orthonormal model-frame translation directions within the span of the unconstrained eigenvectors
    `vecs` (columns, in the solve's scaled unknowns, where a turn counts in metres at the object's size): the
    directions of that span that are mostly translation (a slide along a face, not the spin of a cylinder). An SVD
    of the span's translation block, not a test per eigenvector: a free spin and a free slide of near equal
    curvature come out of eigh mixed."""
    if not vecs.shape[1]:
        return np.zeros((0, 3))
    full = np.zeros((6, vecs.shape[1]))
    full[free] = vecs
    u, sv, _ = np.linalg.svd(full[3:], full_matrices=False)
    return u[:, sv > math.sqrt(0.5)].T


def _slide_along(model: ObjectModel, y: np.ndarray, axis: np.ndarray, reach: float, near: float) -> float:
    """m to move the points y (model frame) along `axis` so that the view's ends lie on the model (at most `reach`).
    Point-to-plane terms cannot see a slide along a face; the ends of the view can (a long bar's ends, a box's far
    edge). The shifts that leave the fewest points farther than `near` from the model form a run: a view as long as
    the model pins it (the run is 2 near long, its middle is the shift); a run cut by the search's bounds is pinned
    by its inner end only; a view shorter than the model (a model grown by faces out of view now) lies anywhere in
    a longer run: the least shift that keeps the view `near` inside its ends."""
    span = reach + near
    shifts = np.arange(-span, span + 0.5 * SLIDE_STEP, SLIDE_STEP)
    along = y @ axis
    # the points farther than span + near from the view's ends stay on the model at every shift tried
    ends = y[(along <= along.min() + span + near) | (along >= along.max() - span - near)]
    moved = (ends[None, :, :] + shifts[:, None, None] * axis).reshape(-1, 3)
    d, _ = model.tree.query(moved, distance_upper_bound=near)
    off = (~np.isfinite(d)).reshape(len(shifts), -1).sum(axis=1)
    fewest = off <= off.min() + max(1, int(SLIDE_SLACK * len(y)))
    centre = int(np.flatnonzero(fewest)[np.argmin(np.abs(shifts[fewest]))])
    lo, hi = centre, centre
    while lo > 0 and fewest[lo - 1]:
        lo -= 1
    while hi < len(shifts) - 1 and fewest[hi + 1]:
        hi += 1
    start, end = float(shifts[lo]), float(shifts[hi])
    cut_low, cut_high = lo == 0, hi == len(shifts) - 1
    if cut_high and not cut_low:
        shift = start + near
    elif cut_low and not cut_high:
        shift = end - near
    elif end - start <= 2.0 * near + SLIDE_PINNED:
        shift = 0.5 * (start + end)
    else:
        shift = float(np.clip(0.0, start + near, end - near))
    return float(np.clip(shift, -reach, reach))


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
    free_vecs = np.zeros((len(free), 0))  # the directions the last iteration's point-to-plane terms left free
    for k in range(iterations):
        n_it = k + 1
        y = (q - t) @ rot  # the points in the model frame: R^T (q - t)
        d, idx = model.tree.query(y, distance_upper_bound=gate)
        ok = d < gate
        if ok.sum() < 6:
            free_vecs = np.zeros((len(free), 0))  # no fit to slide
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
        free_vecs = vecs[:, ~keep]
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
    for axis in _free_translations(free_vecs, free):
        t = t - rot @ (axis * _slide_along(model, (q - t) @ rot, axis, max_distance, min_distance))
    y = (q - t) @ rot
    d, idx = model.tree.query(y, distance_upper_bound=min_distance)
    ok = np.isfinite(d)
    if ok.any():
        r = np.einsum("ij,ij->i", model.normals[idx[ok]], y[ok] - model.points[idx[ok]])
        rmse = float(np.sqrt(np.mean(r * r)))
    return Fit(rot, t, rmse, float(ok.mean()) if len(q) else 0.0, n_it)
