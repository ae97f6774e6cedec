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
"""The pushed body as the planner sees it: centre of mass, mass, inertia and the observed surface points.

The planner searches over pushes a robot can make: a horizontal push in direction d with speed s, touching the
object at a point c of its visible surface. The dynamics model takes *velocities*; a robot or the simulator
needs an *impulse at a contact point*. This module converts one into the other:

    line of push: direction d (unit, horizontal), lateral offset e from the COM (along n = d rotated +90 deg
    about z), height h above the table.
    contact point c = the first surface point the line meets: among the observed points within `tube` of the
        line, the one farthest back along d (where a pusher coming along d touches first). c is a point of the
        cloud, so it lies on the object's observed surface (also for concave shapes, where the convex hull's
        section lies up to centimetres outside the object).
    impulse J = m s d                          (m: the given mass, or the hull estimate below)
    lin_vel v = J / m = s d
    ang_vel w = I^-1 (r x J) = (I/m)^-1 (r x v),  r = c - com (the mass cancels)
    A push below the COM (r_z < 0) tips the object back against its forward topple; above the COM it tips it
    forward. The dataset's pushes were made the same way (sim.push: rays at 5-70 % of the object's height),
    so the learned model knows these initial velocities.

Where the numbers come from:
* from a cloud (preferred): the solid convex hull of the observed points (open3d's qhull), or, for a whole
  cloud (`whole`: every side sampled), the solid it encloses (physdyn_ros.shapes.solid: voxels filled inside the
  sampled surface). COM, inertia per unit mass and mass = volume * density (the simulator's density by default;
  pass the real mass when it is known, it only scales J) are that solid's. The hull is exact for convex objects
  only: it fills a table's legs and a dumbbell's bar, its COM comes out centimetres low and its spin response to
  a push several times off (test/test_solid.py). The planner's body is the hull (the learned model's inputs);
  its physics check simulates pushes on the whole cloud's solid (reweigh). Contacts come from the points
  themselves.
* from a ShapeCode only (a shape feature without points): a solid box with the code's half extents, rotated by
  its heading, centred at its centroid; contacts on the box's sampled faces. Cruder, reported as "box".
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from .. import geometry as geo
from ..conventions import GRAVITY
from ..perception.scene import random_rows
from ..shapes.core import DEFAULT_DENSITY, convex_hull, mass_properties
from ..shapes.solid import solid_mass_properties

#: Points kept for contact search (a random subset of larger clouds: the cost is candidates x points).
MAX_CONTACT_POINTS = 2048
#: Bounds of the tube around a line of push within which points count as on the line (m); in between, the
#: cloud's own median point spacing.
TUBE_RANGE = (0.002, 0.01)
#: Contacts stay this far (m) inside the object's height range: a pusher cannot touch the very bottom edge.
EDGE_MARGIN = 0.003
#: Points this far (m) above the lowest one make the support polygon.
SUPPORT_BAND = 0.004


class BodyError(ValueError):
    """The points or the shape code do not describe a solid that can be pushed."""


@dataclass(frozen=True)
class PushBody:
    """Mass properties and surface points (table-frame axes) of the object as observed."""

    com: np.ndarray  # (3,) m, centre of mass in the table frame (at the observed pose)
    mass: float  # kg, estimate (volume * density) unless given
    inertia_per_mass: np.ndarray  # (3, 3) m^2, inertia about the COM / mass, table axes
    points: np.ndarray  # (N, 3) m, observed surface points relative to the COM
    tube: float  # m, half width of a line of push's tube (see the module docstring)
    source: str  # "hull" or "solid" (from points: the mass distribution's model) or "box" (a shape code's extents)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass) and self.mass > 0):
            raise BodyError(f"mass must be positive and finite, got {self.mass}")
        if len(self.points) < 4:
            raise BodyError("fewer than 4 surface points to push on")

    # -------------------------------------------------------------------------------------------- queries
    @property
    def bottom(self) -> float:
        """Lowest surface point, m above the table frame's origin."""
        return float(self.com[2] + self.points[:, 2].min())

    @property
    def top(self) -> float:
        return float(self.com[2] + self.points[:, 2].max())

    def height_range(self, low: float, high: float) -> tuple[float, float]:
        """Contact heights (m, table frame) a pusher reaching heights [low, high] can use on this object."""
        lo = max(float(low), self.bottom + EDGE_MARGIN)
        hi = min(float(high), self.top - EDGE_MARGIN)
        if lo > hi:
            raise BodyError(f"the object spans heights {self.bottom:.3f}-{self.top:.3f} m, outside the reachable "
                            f"contact heights {low:g}-{high:g} m")
        return lo, hi

    def radius(self) -> float:
        """Largest horizontal distance of a surface point from the COM (m)."""
        return float(np.linalg.norm(self.points[:, :2], axis=1).max())

    def contacts(self, directions: np.ndarray, fractions: np.ndarray, heights: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Contact points (B, 3, table frame) and the lines' lateral offsets e (B,), m from the COM, for lines of push.

        directions (B, 2) unit horizontal; fractions (B,) in [-1, 1]: the line's offset as a share of the
        object's extent to the +n (> 0) or -n (< 0) side of the COM at that height; heights (B,) m, table frame.
        A line that passes through a gap of the surface (a hole, between legs) is moved sideways to the nearest
        points, so every candidate touches the object.
        """
        d = np.asarray(directions, dtype=np.float64)
        n = np.stack([-d[:, 1], d[:, 0]], axis=1)
        p = self.points
        lat = n @ p[:, :2].T  # (B, N)
        along = d @ p[:, :2].T
        dz = np.abs(p[None, :, 2] + self.com[2] - np.asarray(heights, dtype=np.float64)[:, None])
        slab = dz <= np.maximum(dz.min(axis=1, keepdims=True), self.tube)  # never empty
        pos = np.maximum(np.where(slab, lat, -np.inf).max(axis=1), 0.0)
        neg = np.maximum(-np.where(slab, lat, np.inf).min(axis=1), 0.0)
        f = np.asarray(fractions, dtype=np.float64)
        e = np.where(f >= 0, f * pos, f * neg)
        gap = np.where(slab, np.abs(lat - e[:, None]), np.inf)
        tube = slab & (gap <= np.maximum(gap.min(axis=1, keepdims=True), self.tube))
        idx = np.where(tube, along, np.inf).argmin(axis=1)
        return p[idx] + self.com, e

    @cached_property
    def support(self) -> np.ndarray:
        """(K, 2) m, CCW support polygon on the table, relative to the COM: the hull of the lowest points."""
        z = self.points[:, 2]
        return hull_2d(self.points[z <= z.min() + max(SUPPORT_BAND, self.tube), :2])

    def tip_ratios(self, lin_vel: np.ndarray, ang_vel: np.ndarray, friction: float) -> np.ndarray:
        """(B,) kinetic energy of tipping over the support's front edge / the energy barrier of that edge, for
        pushes giving the velocities (B, 3); about 1 and above: the object tips over (a rigid-body estimate:
        small angles, no spin, the nominal friction).

        Tipping forward (about the front edge along the push direction d): the tilt rate w.(z x d) the impulse
        gives (a push above the COM), plus what Coulomb friction at the base adds while the object slides,
        s / (mu g) seconds: the braking pseudo-force mu g at COM height h tips it about that edge when mu h > b
        (b: the edge's distance ahead of the COM), an angular impulse (mu h - b) s / (mu k^2). A push below the
        COM tilts it back, but the table stops the back edge (the angular momentum about the back edge,
        m s z_contact, points forward): counting that backward tilt as a topple would refuse the low, slow pushes
        that move tall objects without tipping them. Very low, fast pushes that flip small objects are bounded by the
        planner's max_spin instead. Barrier: g (sqrt(b^2 + h^2) - h) per unit mass; k^2 = a.(I/m).a + b^2 + h^2
        about the edge (axis a)."""
        v = np.asarray(lin_vel, dtype=np.float64)
        s = np.linalg.norm(v[:, :2], axis=1)
        d = v[:, :2] / np.maximum(s, 1e-9)[:, None]
        axis = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)  # z x d: + tips the top along d
        tilt = np.maximum(np.einsum("bi,bi->b", np.asarray(ang_vel, dtype=np.float64), axis), 0.0)
        h = max(-self.points[:, 2].min(), 1e-4)  # COM height above the support
        b = np.maximum(d @ self.support.T, 0.0).max(axis=1)  # front edge distance along d
        k2 = np.einsum("bi,ij,bj->b", axis, self.inertia_per_mass, axis) + b * b + h * h
        mu = max(float(friction), 1e-3)
        rate = tilt + np.maximum(mu * h - b, 0.0) * s / (mu * k2)
        barrier = GRAVITY * (np.sqrt(b * b + h * h) - h)
        return 0.5 * k2 * rate * rate / np.maximum(barrier, 1e-9)

    def reweigh(self, other: "PushBody", lin_vel: np.ndarray, ang_vel: np.ndarray) -> np.ndarray:
        """Angular velocities (B, 3) that `other` (the same object weighed otherwise) gets from the impulses
        that give this body lin_vel, ang_vel (B, 3): the same J = m v along the same line, whose moment per mass
        about this COM is (I/m) w, taken about other's COM. The linear velocities stay."""
        v = np.atleast_2d(np.asarray(lin_vel, dtype=np.float64))
        w = np.atleast_2d(np.asarray(ang_vel, dtype=np.float64))
        moment = w @ self.inertia_per_mass.T + np.cross(self.com - other.com, v)
        return np.linalg.solve(other.inertia_per_mass, moment.T).T

    def angular_velocity(self, lin_vel: np.ndarray, contacts: np.ndarray) -> np.ndarray:
        """(B, 3) angular velocity right after impulses m * lin_vel (B, 3) applied at contacts (B, 3)."""
        r = np.asarray(contacts, dtype=np.float64) - self.com
        return np.linalg.solve(self.inertia_per_mass, np.cross(r, lin_vel).T).T


# --------------------------------------------------------------------------------------------- construction
def hull_2d(points: np.ndarray) -> np.ndarray:
    """Convex hull (K, 2), counter-clockwise, of 2-D points (scipy's qhull); the points themselves if flat."""
    pts = np.asarray(points, dtype=np.float64)
    try:
        return pts[ConvexHull(pts).vertices]  # qhull lists 2-D hull vertices counter-clockwise
    except (QhullError, ValueError):
        return pts


def _contact_points(points: np.ndarray, seed: int = 0) -> tuple[np.ndarray, float]:
    """At most MAX_CONTACT_POINTS of `points` and the tube half width from their median spacing."""
    points = random_rows(points, MAX_CONTACT_POINTS, np.random.default_rng(seed))
    dist, _ = cKDTree(points).query(points, k=2)
    spacing = float(np.median(dist[:, 1]))
    return points, float(np.clip(spacing, *TUBE_RANGE))


def body_from_cloud(cloud: np.ndarray, density: float = DEFAULT_DENSITY, mass: float | None = None,
                    whole: bool = False) -> PushBody:
    """PushBody of an observed cloud (N, 3) in the table frame; contacts on the cloud. Its mass distribution is
    the solid convex hull's, or, for a `whole` cloud (every side of the object sampled), the solid the cloud
    encloses (shapes.solid: right for concave objects too, whose hull puts the centre of mass centimetres off)."""
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 4:
        raise BodyError(f"need an (N >= 4, 3) cloud to estimate the body, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise BodyError("cloud contains NaN or inf")
    try:
        v, f = convex_hull(pts)
        mp = solid_mass_properties(pts, density) if whole else mass_properties(v, f, density=density)
    except ValueError as exc:
        raise BodyError(f"cloud does not enclose a solid: {exc}") from None
    surface, tube = _contact_points(pts)
    m = mp.mass if mass is None else float(mass)
    return PushBody(com=mp.com, mass=m, inertia_per_mass=mp.inertia / mp.mass, points=surface - mp.com, tube=tube,
                    source="solid" if whole else "hull")


def box_surface(half_extents: np.ndarray, spacing: float = 0.005, max_points: int = 1500) -> np.ndarray:
    """Points on the six faces of a box centred at the origin (grids of about `spacing`, at most ~max_points)."""
    h = np.asarray(half_extents, dtype=np.float64)
    area = 8.0 * (h[0] * h[1] + h[1] * h[2] + h[0] * h[2])
    spacing = max(spacing, float(np.sqrt(area / max_points)))
    faces = []
    for axis in range(3):
        u, w = [a for a in range(3) if a != axis]
        gu = np.linspace(-h[u], h[u], max(2, int(np.ceil(2 * h[u] / spacing)) + 1))
        gw = np.linspace(-h[w], h[w], max(2, int(np.ceil(2 * h[w] / spacing)) + 1))
        uu, ww = np.meshgrid(gu, gw, indexing="ij")
        for sign in (-1.0, 1.0):
            face = np.zeros((uu.size, 3))
            face[:, u], face[:, w], face[:, axis] = uu.ravel(), ww.ravel(), sign * h[axis]
            faces.append(face)
    return np.unique(np.round(np.concatenate(faces), 9), axis=0)


def body_from_box(centroid: np.ndarray, half_extents: np.ndarray, heading: float,
                  density: float = DEFAULT_DENSITY, mass: float | None = None) -> PushBody:
    """PushBody of a solid box (half extents in a frame rotated by `heading` about z) centred at `centroid`."""
    h = np.asarray(half_extents, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise BodyError(f"half extents must be positive, got {h.tolist()}")
    a, b, c = h
    local = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) / 3.0
    rot = geo.yaw_matrix(float(heading))
    surface, tube = _contact_points(box_surface(h) @ rot.T)
    m = 8.0 * a * b * c * density if mass is None else float(mass)
    return PushBody(com=np.asarray(centroid, dtype=np.float64).reshape(3), mass=m,
                    inertia_per_mass=rot @ local @ rot.T, points=surface, tube=tube, source="box")
