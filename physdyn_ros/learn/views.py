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
"""Partial clouds as a depth camera sees them, for training and evaluation on realistic inputs.

A robot's depth camera sees one side of an object: the faces turned away and the bottom on the table are
missing, and the centroid of what is seen lies cm from the centre of mass.
`visible` is an orthographic z-buffer along the viewing direction (numpy, vectorised over a batch): a point is
seen when it lies within `tol` of the front-most point of its image cell. Sensor noise is Gaussian.
"""
from __future__ import annotations

import numpy as np

#: Camera elevation over the table plane (rad): depth cameras above a table look down 20-70 degrees.
ELEVATION = (np.radians(20.0), np.radians(70.0))


def random_view_dirs(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) unit vectors from the object towards the camera: any azimuth, elevation within ELEVATION."""
    az = rng.uniform(-np.pi, np.pi, n)
    el = rng.uniform(*ELEVATION, n)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


def visible(points: np.ndarray, view_dir: np.ndarray, cell_factor: float = 2.0) -> np.ndarray:
    """(B, N) mask of the surface points (B, N, 3) a camera far away along view_dir (B, 3) sees.

    An orthographic z-buffer whose cells are `cell_factor` point spacings wide (the spacing of N points over the
    bounding box's surface), so a sampled surface leaves no holes for hidden points to show through; a point is
    seen within 0.9 cell of its cell's front-most point (an inclined face changes depth across a cell). Points
    of hidden faces next to a silhouette edge leak through (a thin strip of a hidden face), as edge pixels do on a
    sensor.
    """
    pts = np.asarray(points, dtype=np.float64)
    d = np.asarray(view_dir, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    b, n, _ = pts.shape
    ext = pts.max(axis=1) - pts.min(axis=1)
    area = 2.0 * (ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0])
    cell = (cell_factor * np.sqrt(np.maximum(area, 1e-8) / n))[:, None]  # (B, 1)
    tol = 0.9 * cell
    # an image-plane basis (u, v) perpendicular to d
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(d, u)
    near = np.einsum("bnk,bk->bn", pts, d)  # larger = closer to the camera
    iu = np.floor(np.einsum("bnk,bk->bn", pts, u) / cell).astype(np.int64)
    iv = np.floor(np.einsum("bnk,bk->bn", pts, v) / cell).astype(np.int64)
    iu -= iu.min(axis=1, keepdims=True)
    iv -= iv.min(axis=1, keepdims=True)
    width = int(iv.max()) + 1
    key = (np.arange(b)[:, None] * (int(iu.max()) + 1) + iu) * width + iv  # one id per (sample, cell)
    flat_key, flat_near = key.ravel(), near.ravel()
    order = np.lexsort((-flat_near, flat_key))  # per cell, the nearest first
    sk = flat_key[order]
    first = np.ones(len(sk), dtype=bool)
    first[1:] = sk[1:] != sk[:-1]
    front = np.maximum.reduceat(flat_near[order], np.flatnonzero(first))
    group = np.cumsum(first) - 1
    seen = np.empty(len(sk), dtype=bool)
    seen[order] = flat_near[order] >= front[group] - np.broadcast_to(tol, (b, n)).ravel()[order]
    return seen.reshape(b, n)


def sample_visible(mask: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(B, count) indices of visible points per row, uniform; with repeats when fewer are visible."""
    b, n = mask.shape
    keys = rng.random((b, n)) + (~mask)  # visible points sort first, in random order
    order = np.argsort(keys, axis=1)
    n_vis = np.maximum(mask.sum(axis=1), 1)
    pick = (np.arange(count)[None, :] % n_vis[:, None])  # cycle through the visible ones
    return np.take_along_axis(order, pick, axis=1)
