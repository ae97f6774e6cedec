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
"""The `Shape` type and the mesh maths it needs (numpy, trimesh, open3d; no pybullet).

A shape lives in its *object frame*: origin at the centre of mass of the solid (uniform density), z = the
shape's up axis (upright when the orientation is the identity). Mass properties are computed exactly from the
closed triangle mesh by trimesh (its polyhedral mass properties: the divergence theorem over the faces), so they
follow any per-axis scale.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from ..conventions import NUM_POINTS

#: Density used for every simulated object, kg/m^3 (constant across a dataset, as in the paper). The value only
#: sets the mass scale: with impulses drawn as mass * velocity and Coulomb friction, trajectories do not depend on it.
DEFAULT_DENSITY: float = 500.0


@dataclass(frozen=True)
class MassProperties:
    """Mass properties of a solid of uniform density, in the object frame."""

    volume: float  # m^3
    mass: float  # kg
    com: np.ndarray  # (3,) m, centre of mass (~0 for a Shape, whose origin is its COM)
    inertia: np.ndarray  # (3, 3) kg m^2, inertia tensor about the COM, object axes
    principal_moments: np.ndarray  # (3,) kg m^2, eigenvalues of `inertia` (ascending)
    principal_axes: np.ndarray  # (3, 3) rotation, columns = principal axes in the object frame (det +1)


def _trimesh_mass(vertices: np.ndarray, faces: np.ndarray, density: float = 1.0):
    """trimesh's mass properties (volume, center_mass, inertia about it) of a triangle soup; signed volume (< 0
    for an inward-wound mesh); a centre of mass of zeros where the volume is zero."""
    from trimesh.triangles import mass_properties as trimesh_mass_properties

    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)].reshape(-1, 3, 3)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero volume: no centre of mass (checked by callers)
        mp = trimesh_mass_properties(tri, density=density)
    if not np.all(np.isfinite(mp.center_mass)):
        mp = trimesh_mass_properties(tri, density=density, center_mass=np.zeros(3))
    return mp


def mesh_moments(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, first moment (3,) and second moment matrix ∫ x x^T dV (3, 3) of a closed, outward-oriented mesh
    (signed: negative for an inward-wound mesh), from trimesh's mass properties."""
    mp = _trimesh_mass(vertices, faces)
    volume, com = float(mp.volume), np.asarray(mp.center_mass, dtype=np.float64)
    # inertia about the COM I = tr(C) Id - C with C = ∫ (x - com)(x - com)^T dV, so C = tr(I) / 2 Id - I
    c_com = 0.5 * np.trace(mp.inertia) * np.eye(3) - mp.inertia
    return volume, volume * com, c_com + volume * np.outer(com, com)


def mass_properties(vertices: np.ndarray, faces: np.ndarray, density: float = DEFAULT_DENSITY,
                    scale: np.ndarray | tuple[float, float, float] = (1.0, 1.0, 1.0)) -> MassProperties:
    """Mass properties of the closed mesh scaled per axis by `scale` (object frame), at `density` kg/m^3."""
    scale = np.asarray(scale, dtype=np.float64).reshape(3)
    if np.any(scale <= 0):
        raise ValueError(f"scale must be positive, got {scale.tolist()}")
    if not density > 0:
        raise ValueError(f"density must be positive, got {density}")
    mp = _trimesh_mass(np.asarray(vertices, dtype=np.float64) * scale, faces, density)
    volume = float(mp.volume)
    if not volume > 1e-12:
        raise ValueError(f"mesh has no positive volume ({volume:.3g} m^3): it is not closed or its faces point inwards")
    com = np.asarray(mp.center_mass, dtype=np.float64)
    inertia = np.asarray(mp.inertia, dtype=np.float64)  # about the COM, object axes (trimesh: symmetric)
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return MassProperties(volume=volume, mass=volume * density, com=com, inertia=inertia,
                          principal_moments=moments, principal_axes=axes)


def orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip all faces if the mesh encloses a negative signed volume (consistently inward-wound mesh)."""
    volume, _, _ = mesh_moments(vertices, faces)
    return faces[:, ::-1].copy() if volume < 0 else faces


def _o3d_mesh(vertices: np.ndarray, faces: np.ndarray):
    import open3d as o3d

    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, dtype=np.float64)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, dtype=np.int32)))


def surface_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (m) from each of `points` (N, 3) to the surface of the mesh (open3d's raycasting scene); used to
    check that a planned contact point lies on an object."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.asarray(faces, dtype=np.uint32)))
    query = o3d.core.Tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3))
    return scene.compute_distance(query).numpy().astype(np.float64)


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convex hull (vertices, outward faces) of a point set, via open3d's qhull."""
    import open3d as o3d

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 4:
        raise ValueError(f"a convex hull needs at least 4 points, got {len(pts)}")
    try:
        hull, _ = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).compute_convex_hull()
    except RuntimeError as exc:  # qhull refuses flat / degenerate sets
        raise ValueError(f"points do not span a 3D convex hull: {exc}") from None
    v = np.asarray(hull.vertices, dtype=np.float64)
    f = orient_outward(v, np.asarray(hull.triangles, dtype=np.int64))
    return v, f


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int = NUM_POINTS, seed: int = 0) -> np.ndarray:
    """`n` points uniformly distributed over the mesh surface (area-weighted), float32, via open3d.

    open3d's sampler draws from its global generator; seeding it right before the call makes the cloud a pure
    function of (mesh, seed).
    """
    import open3d as o3d

    o3d.utility.random.seed(int(seed) % (2**31))
    pcd = _o3d_mesh(vertices, faces).sample_points_uniformly(number_of_points=int(n))
    return np.asarray(pcd.points, dtype=np.float32)


@dataclass(eq=False)
class Shape:
    """A rigid object shape in its object frame (origin = centre of mass, z = up, metres).

    `convex` says whether the convex hull is an exact collision shape (convex solids); otherwise the simulator
    uses a convex decomposition: the shape's own `parts` when it has them, else V-HACD. `points` are NUM_POINTS
    uniform surface samples in the same frame.

    `parts` (optional, shapes built from convex pieces): vertex arrays (P_i, 3) whose convex hulls together
    make up the solid, in the same frame. They are an exact collision decomposition; the mesh (`vertices`,
    `faces`) stays the surface of the whole solid, so mass properties and clouds come from the union.
    """

    name: str
    category: str
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64, outward winding
    convex: bool
    points: np.ndarray  # (NUM_POINTS, 3) float32
    params: dict = field(default_factory=dict)  # generator parameters (procedural) or source file (loaded)
    parts: tuple[np.ndarray, ...] | None = None  # convex pieces (vertex arrays), object frame; None: not known
    # mass properties at density 1 when they are not the mesh's (a cloud's hull holding the solid the cloud
    # encloses, shapes.solid); unscaled shapes only
    solid: MassProperties | None = None
    _hull: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False)

    @property
    def extents(self) -> np.ndarray:
        """(3,) axis-aligned size of the unscaled shape, m."""
        return self.vertices.max(0) - self.vertices.min(0)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of the unscaled shape in the object frame."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    def mass_properties(self, scale: np.ndarray | tuple[float, float, float] = (1.0, 1.0, 1.0),
                        density: float = DEFAULT_DENSITY) -> MassProperties:
        """Mass properties of the shape scaled per axis by `scale`, at `density` kg/m^3."""
        if self.solid is None:
            return mass_properties(self.vertices, self.faces, density, scale)
        if not np.allclose(np.asarray(scale, dtype=np.float64), 1.0):
            raise ValueError("a shape with given mass properties (solid) cannot be scaled")
        if not density > 0:
            raise ValueError(f"density must be positive, got {density}")
        s = self.solid
        return replace(s, mass=s.volume * density, inertia=s.inertia * density,
                       principal_moments=s.principal_moments * density)

    def hull(self) -> tuple[np.ndarray, np.ndarray]:
        """Convex hull (vertices, faces) of the unscaled shape (cached)."""
        if self._hull is None:
            self._hull = convex_hull(self.vertices)
        return self._hull

    def fingerprint(self) -> str:
        """sha256 of the geometry: a cache key for derived data (convex decompositions)."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(self.faces, dtype=np.int64).tobytes())
        for part in self.parts or ():  # shapes without parts keep their earlier fingerprints (V-HACD cache keys)
            h.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
        return h.hexdigest()


def make_shape(name: str, category: str, vertices: np.ndarray, faces: np.ndarray, convex: bool,
               seed: int = 0, params: dict | None = None, num_points: int = NUM_POINTS,
               parts: list[np.ndarray] | tuple[np.ndarray, ...] | None = None) -> Shape:
    """Build a Shape from a closed mesh in any frame with z up: orients it outward, moves the origin to its centre
    of mass and samples the surface cloud. `parts` (convex pieces of the solid, same frame) move with it."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = orient_outward(vertices, np.asarray(faces, dtype=np.int64))
    mp = mass_properties(vertices, faces, density=1.0)
    vertices = vertices - mp.com
    points = sample_surface(vertices, faces, num_points, seed)
    if parts is not None:
        parts = tuple(np.asarray(q, dtype=np.float64).reshape(-1, 3) - mp.com for q in parts)
        if not parts:
            raise ValueError("parts must hold at least one convex piece")
    return Shape(name=name, category=category, vertices=vertices, faces=faces, convex=bool(convex),
                 points=points, params=dict(params or {}), parts=parts)


def shape_from_points(points: np.ndarray, name: str = "hull", category: str = "points",
                      solid: MassProperties | None = None) -> Shape:
    """A convex Shape made of the convex hull of a point cloud given in its object frame.

    The cloud frame is kept as is (no re-centring): its origin is taken to be the centre of mass, as for the
    canonical clouds of a dataset. The inertia is that of the solid hull about this origin, or `solid`'s (mass
    properties at density 1 in the same frame: the hull collides, the solid weighs).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(pts)):
        raise ValueError("point cloud contains NaN or inf")
    v, f = convex_hull(pts)
    if solid is not None:
        solid = replace(solid, mass=solid.volume, inertia=solid.inertia * (solid.volume / solid.mass),
                        principal_moments=solid.principal_moments * (solid.volume / solid.mass))
    return Shape(name=name, category=category, vertices=v, faces=f, convex=True,
                 points=np.asarray(points, dtype=np.float32).reshape(-1, 3), params={"source": "points"},
                 solid=solid)
