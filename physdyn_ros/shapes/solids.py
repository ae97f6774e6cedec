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
"""Solids made of convex pieces, and resting poses (numpy + open3d's qhull; no pybullet, no scipy).

* Primitive point sets (boxes, n-gon prisms and frustums, ellipsoids, lathes) whose convex hulls are the pieces
  of a composed solid.
* `union_surface`: the boundary of a union of convex pieces as one outward triangle mesh, for pieces that
  touch face to face or overlap. Every hull triangle of every piece is clipped against the interior of the
  other pieces (convex polygon minus convex polytope, one half-space at a time); faces that touch face to face
  (coplanar, opposite normals) cancel, coplanar faces with the same normal are kept once. The result has
  T-junctions but is a closed, outward surface as a point set, so the divergence-theorem mass properties of
  `core.mass_properties` are exact for the union (overlaps are counted once) and surface samples never fall
  inside the solid.
* `support_margin` / `rest_on_stable_face`: how far the centre of mass lies inside the support polygon of a
  solid resting on the plane z = min, and the rotation that puts a solid on its most stable hull face.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .core import convex_hull, mass_properties

_TOL = 1e-9  # m: coplanarity / on-plane tolerance (pieces are built to touch exactly)
_AREA = 1e-12  # m^2: polygons smaller than this are numerical slivers


# ------------------------------------------------------------------------------------------------ primitives
def box_points(lo: ArrayLike, hi: ArrayLike) -> np.ndarray:
    """The 8 corners of the axis-aligned box [lo, hi]."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def polygon(n: int, radius: float, phase: float = 0.0) -> np.ndarray:
    """(n, 2) vertices of a regular n-gon of circumradius `radius`, counter-clockwise from angle `phase`."""
    a = phase + 2 * np.pi * np.arange(n) / n
    return radius * np.stack([np.cos(a), np.sin(a)], 1)


def flat_phase(n: int, direction: float = -np.pi / 2) -> float:
    """Phase of a regular n-gon (see `polygon`) that puts the middle of an edge in `direction` (an edge, not a
    corner, faces that way: a polygonal disc standing on it rests on a face)."""
    return float((direction - np.pi / n) % (2 * np.pi / n))


def frustum_points(section0: np.ndarray, z0: float, section1: np.ndarray, z1: float) -> np.ndarray:
    """Points of a prism / frustum / antiprism between two (k, 2) horizontal sections at heights z0 < z1."""
    s0, s1 = np.asarray(section0, dtype=np.float64), np.asarray(section1, dtype=np.float64)
    return np.vstack([np.column_stack([s0, np.full(len(s0), z0)]), np.column_stack([s1, np.full(len(s1), z1)])])


def ellipsoid_points(radii: Sequence[float] | np.ndarray, n_lat: int = 10, n_lon: int = 20,
                     exponents: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Points on a superellipsoid centred at 0 with semi-axes `radii` and exponents (e1 vertical, e2
    horizontal); (1, 1) is an ellipsoid, small exponents a rounded box, 2 an octahedron. Poles included."""
    a, b, c = (float(r) for r in radii)
    e1, e2 = (float(e) for e in exponents)
    eta = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)[1:-1]
    om = -np.pi + 2 * np.pi * np.arange(n_lon) / n_lon

    def spow(x, e):
        return np.sign(x) * np.abs(x) ** e

    ce, se = spow(np.cos(eta), e1)[:, None], spow(np.sin(eta), e1)[:, None]
    co, so = spow(np.cos(om), e2)[None, :], spow(np.sin(om), e2)[None, :]
    pts = np.stack([a * ce * co, b * ce * so, np.broadcast_to(c * se, (len(eta), n_lon))], -1).reshape(-1, 3)
    return np.vstack([pts, [[0.0, 0.0, -c], [0.0, 0.0, c]]])


def rotate_to_axis(points: np.ndarray, axis: str) -> np.ndarray:
    """Points built along z, re-expressed along `axis` ("x", "y" or "z")."""
    p = np.asarray(points, dtype=np.float64)
    if axis == "z":
        return p.copy()
    if axis == "x":
        return p[:, [2, 1, 0]] * np.array([1.0, 1.0, -1.0])  # z -> x (a proper rotation about y)
    if axis == "y":
        return p[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # z -> y (a proper rotation about x)
    raise ValueError(f"axis must be x, y or z, got {axis!r}")


def lathe_sections(radii: np.ndarray, heights: np.ndarray, segments: int, phase: float = 0.0) -> list[np.ndarray]:
    """Convex pieces (frustums between consecutive rings) of the solid of revolution with rings (radii[i], z =
    heights[i]), as vertex arrays: together they are the solid `paper.lathe` builds from that profile."""
    ring = polygon(segments, 1.0, phase)
    return [frustum_points(ring * r0, z0, ring * r1, z1)
            for r0, r1, z0, z1 in zip(radii[:-1], radii[1:], heights[:-1], heights[1:])]


# --------------------------------------------------------------------------------------------- union surface
def _planes(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct supporting planes (normals (m, 3), offsets (m,)) n.x <= d of a convex hull."""
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.einsum("ij,ij->i", n, tri[:, 0])
    keep: list[int] = []
    done = np.zeros(len(n), dtype=bool)
    for i in range(len(n)):
        if not done[i]:
            keep.append(i)
            done |= (n @ n[i] > 1 - 1e-9) & (np.abs(d - d[i]) < _TOL)
    return n[keep], d[keep]


def _clip(poly: np.ndarray, n: np.ndarray, d: float, keep_below: bool) -> np.ndarray | None:
    """Sutherland-Hodgman: the part of a convex polygon (k, 3) with n.x <= d (keep_below) or n.x >= d."""
    s = poly @ n - d
    if not keep_below:
        s = -s
    out = []
    k = len(poly)
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        sa, sb = s[i], s[(i + 1) % k]
        if sa <= 0:
            out.append(a)
        if (sa < 0 < sb) or (sb < 0 < sa):
            out.append(a + (b - a) * (sa / (sa - sb)))
    return np.asarray(out) if len(out) >= 3 else None


def _area(poly: np.ndarray | None) -> float:
    if poly is None:
        return 0.0
    return 0.5 * float(np.linalg.norm(np.cross(poly[1:-1] - poly[0], poly[2:] - poly[0]).sum(0)))


def _subtract(poly: np.ndarray, normal: np.ndarray, planes: tuple[np.ndarray, np.ndarray],
              keep_same: bool) -> list[np.ndarray]:
    """A convex polygon (on a face with outward `normal`) minus the interior of a convex piece given by its
    planes. A plane of the piece that holds the polygon counts as 'inside' when it faces the other way (the two
    faces touch: both are interior) and, for the same direction, unless `keep_same` (the face is kept once)."""
    N, D = planes
    s = poly @ N.T - D  # (k, m)
    on = np.all(np.abs(s) <= _TOL, axis=0)
    for k in np.flatnonzero(on):
        if N[k] @ normal > 0 and keep_same:
            return [poly]
    active = ~on
    if np.any(np.all(s[:, active] >= -_TOL, axis=0)):  # on or outside one of the piece's planes
        return [poly]
    out: list[np.ndarray] = []
    inside = poly
    for k in np.flatnonzero(active):
        si = inside @ N[k] - D[k]
        if np.all(si <= _TOL):
            continue
        outer = _clip(inside, N[k], D[k], keep_below=False)
        clipped = _clip(inside, N[k], D[k], keep_below=True)
        if outer is not None and _area(outer) > _AREA:
            out.append(outer)
        if clipped is None or _area(clipped) <= _AREA:
            return [poly]  # the overlap is a sliver: keep the polygon whole
        inside = clipped
    return out


def union_surface(pieces: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Outward triangle mesh (vertices, faces) of the boundary of the union of the convex hulls of `pieces`."""
    hulls = [convex_hull(p) for p in pieces]
    planes = [_planes(v, f) for v, f in hulls]
    boxes = [(v.min(0) - 1e-7, v.max(0) + 1e-7) for v, _ in hulls]
    polys: list[np.ndarray] = []
    for i, (v, f) in enumerate(hulls):
        tris = v[f]
        lo, hi = tris.min(1), tris.max(1)
        # Pieces each triangle may reach: bounding boxes overlap and no plane of the piece has the whole
        # triangle on or outside it, except planes holding the triangle (touching faces).
        near = np.zeros((len(tris), len(hulls)), dtype=bool)
        for j in range(len(hulls)):
            if j == i:
                continue
            cand = np.all(hi >= boxes[j][0], 1) & np.all(lo <= boxes[j][1], 1)
            if cand.any():
                s = np.einsum("tvc,mc->tvm", tris[cand], planes[j][0]) - planes[j][1]
                outside = np.all(s >= -_TOL, 1) & ~np.all(np.abs(s) <= _TOL, 1)
                cand[np.flatnonzero(cand)] = ~outside.any(1)
            near[:, j] = cand
        for t, tri in enumerate(tris):
            pieces_left = [tri]
            if near[t].any():
                normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
                normal /= np.linalg.norm(normal)
                for j in np.flatnonzero(near[t]).tolist():
                    pieces_left = [q for p in pieces_left for q in _subtract(p, normal, planes[j], keep_same=j > i)]
                    if not pieces_left:
                        break
            polys += pieces_left
    # Fan-triangulate the convex polygons and merge coincident vertices.
    tris = np.concatenate([np.stack([np.broadcast_to(p[0], (len(p) - 2, 3)), p[1:-1], p[2:]], 1) for p in polys])
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    tris = tris[area > _AREA]
    flat = tris.reshape(-1, 3)
    key = np.round(flat / 1e-10).astype(np.int64)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    verts = np.zeros((len(uniq), 3))
    verts[inverse.reshape(-1)] = flat
    faces = inverse.reshape(-1, 3).astype(np.int64)
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    used, faces = np.unique(faces, return_inverse=True)
    return verts[used], faces.reshape(-1, 3).astype(np.int64)


def closure_error(vertices: np.ndarray, faces: np.ndarray) -> float:
    """|sum of the face area vectors| relative to the total area: 0 for a closed surface (T-junctions allowed).
    A closed surface encloses the same signed volume wherever the origin is."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return float(np.linalg.norm(cr.sum(0)) / np.linalg.norm(cr, axis=1).sum())


# ----------------------------------------------------------------------------------------------- resting pose
def _hull_2d(p: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull of 2D points (monotone chain), without collinear points."""
    pts = np.unique(np.round(np.asarray(p, dtype=np.float64), 12), axis=0)
    if len(pts) < 3:
        return pts

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[np.ndarray] = []
    upper: list[np.ndarray] = []
    for q in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], q) <= 1e-15:
            lower.pop()
        lower.append(q)
    for q in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], q) <= 1e-15:
            upper.pop()
        upper.append(q)
    return np.asarray(lower[:-1] + upper[:-1])


def _polygon_margin(poly: np.ndarray, q: np.ndarray) -> float:
    """Signed distance from q to the boundary of a CCW convex polygon: > 0 inside."""
    if len(poly) < 3:
        return -np.inf
    a, b = poly, np.roll(poly, -1, axis=0)
    e = b - a
    inward = np.stack([-e[:, 1], e[:, 0]], 1) / np.linalg.norm(e, axis=1, keepdims=True)
    return float(np.min(np.einsum("ij,ij->i", q[None, :] - a, inward)))


def support_margin(vertices: np.ndarray, com: np.ndarray, tol: float = 1e-6) -> float:
    """Distance (m) from the centre of mass's ground projection to the edge of the support polygon (the hull of
    the vertices within `tol` of the lowest z) of a solid resting on z = min; negative: it tips over."""
    v = np.asarray(vertices, dtype=np.float64)
    base = v[v[:, 2] <= v[:, 2].min() + tol][:, :2]
    return _polygon_margin(_hull_2d(base), np.asarray(com, dtype=np.float64)[:2])


def _rotation_to_down(n: np.ndarray) -> np.ndarray:
    """Rotation matrix taking the unit vector n to -z."""
    target = np.array([0.0, 0.0, -1.0])
    c = float(n @ target)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(n, target)
    s = np.linalg.norm(axis)
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def rest_on_stable_face(vertices: np.ndarray, faces: np.ndarray,
                        within: float | None = None) -> tuple[np.ndarray, float]:
    """The rotation (3, 3) that puts the solid (closed mesh) on its most stable hull face, and that face's
    stability (margin of the centre of mass inside the face / height of the centre of mass above it). `within`
    (rad): only faces whose outward normal lies within that angle of -z (the solid keeps roughly its pose)."""
    v = np.asarray(vertices, dtype=np.float64)
    com = mass_properties(v, faces, density=1.0).com
    hv, hf = convex_hull(v)
    tri = hv[hf]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = np.einsum("ij,ij->i", n, tri[:, 0])
    best, best_score = np.eye(3), -np.inf
    done = np.zeros(len(n), dtype=bool)
    for i in range(len(n)):
        if done[i] or (within is not None and -n[i, 2] < np.cos(within)):
            continue
        group = (~done) & (n @ n[i] > 1 - 1e-7) & (np.abs(d - d[i]) < 1e-7)
        done |= group
        rot = _rotation_to_down(n[i])
        facet = (tri[group].reshape(-1, 3) - com) @ rot.T
        height = float(d[i] - n[i] @ com)
        score = _polygon_margin(_hull_2d(facet[:, :2]), np.zeros(2)) / max(height, 1e-12)
        if score > best_score + 1e-9:
            best, best_score = rot, score
    return best, float(best_score)
