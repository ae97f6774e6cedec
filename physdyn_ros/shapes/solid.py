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
"""The solid a whole cloud encloses, and its mass properties at uniform density.

The convex hull of a cloud is the exact contact geometry of a lone object on a plane (only hull points can touch
it), but its mass distribution is wrong for concave objects: it fills the space between a table's legs (its
centre of mass comes out 2-6 cm low) and the bar of a dumbbell, and it gives both too small a radius of gyration.
Re-simulating the hull then tips objects the real one slides. The solid here is built on a voxel grid (`cells`
voxels along the longest side): the voxels holding points, dilated by the cloud's own sample spacing (the distance
to the `neighbours`-th nearest point, median) so that the sampled surface closes, the enclosed cavities filled
(scipy.ndimage.binary_fill_holes), eroded back by the same radius, united with the voxels holding points (thin
walls and legs keep their one voxel). On the held-out families' whole clouds its volume is within 0.7-1.2x of
the mesh's and its inertia per mass within about 10 % (the hull's: 1.4-6x the volume, inertia up to 45 % off).

It needs the whole surface: one camera's view is an open shell that encloses nothing, so its "solid" is a thin
dish on the visible side. Callers use it only for clouds they know to be whole.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .core import DEFAULT_DENSITY, MassProperties, Shape, shape_from_points

__all__ = ["cloud_solid", "solid_mass_properties", "solid_hull"]

#: Voxels along the cloud's longest side.
CELLS = 32
#: The sample spacing is the distance to this many-th nearest point (median over the cloud).
NEIGHBOURS = 8


def cloud_solid(points: np.ndarray, cells: int = CELLS, neighbours: int = NEIGHBOURS
                ) -> tuple[np.ndarray, float]:
    """Centres (K, 3) of the voxels of the solid that the whole cloud `points` (N, 3) encloses, and the voxel
    edge (m). Raises ValueError for clouds that are too small, flat or not finite."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) <= neighbours:
        raise ValueError(f"need an (N > {neighbours}, 3) cloud for its solid, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("cloud contains NaN or inf")
    lo = pts.min(axis=0)
    size = float((pts.max(axis=0) - lo).max())
    if not size > 1e-4:
        raise ValueError(f"cloud spans {size:.2g} m: no solid to estimate")
    h = size / int(cells)
    spacing = float(np.median(cKDTree(pts).query(pts, k=neighbours + 1)[0][:, neighbours]))
    r = max(1, int(np.ceil(spacing / h)))
    pad = r + 2
    idx = np.floor((pts - lo) / h).astype(np.int64) + pad
    occupied = np.zeros(tuple(idx.max(axis=0) + pad + 1), dtype=bool)
    occupied[tuple(idx.T)] = True
    ball = ndimage.iterate_structure(ndimage.generate_binary_structure(3, 1), r)
    closed = ndimage.binary_fill_holes(ndimage.binary_dilation(occupied, ball))
    solid = ndimage.binary_erosion(closed, ball) | occupied
    return (np.argwhere(solid) - pad + 0.5) * h + lo, h


def solid_mass_properties(points: np.ndarray, density: float = DEFAULT_DENSITY) -> MassProperties:
    """Mass properties (frame of `points`) of cloud_solid(points) at uniform `density` kg/m^3."""
    if not density > 0:
        raise ValueError(f"density must be positive, got {density}")
    centres, h = cloud_solid(points)
    volume = len(centres) * h ** 3
    mass = volume * float(density)
    com = centres.mean(axis=0)
    d = centres - com
    cov = d.T @ d / len(centres)
    # point masses at the voxel centres plus each voxel's own inertia (a cube: h^2 / 6 per unit mass)
    inertia = mass * (np.trace(cov) * np.eye(3) - cov + h * h / 6.0 * np.eye(3))
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return MassProperties(volume=volume, mass=mass, com=com, inertia=inertia, principal_moments=moments,
                          principal_axes=axes)


def solid_hull(points: np.ndarray) -> tuple[Shape, np.ndarray]:
    """The convex hull of `points` (N, 3) weighing as the solid they enclose: a Shape whose object frame is the
    points' frame moved to that solid's centre of mass (what the simulator takes as the body's origin), and that
    centre of mass in the points' frame. The hull collides (exact for a lone object on a plane), the solid weighs."""
    pts = np.asarray(points, dtype=np.float64)
    mp = solid_mass_properties(pts, 1.0)
    com = mp.com
    # the inertia is already about the solid's COM: the Shape's origin, so its COM there is zero
    return shape_from_points(pts - com, solid=replace(mp, com=np.zeros(3))), com
