"""The pushed body as the planner sees it: centre of mass, mass, inertia and the cross-section at COM height.

The planner searches over *velocities* (what the dynamics model takes); a robot or the simulator needs an
*impulse at a contact point*. This module converts one into the other, for a horizontal push at the height of
the centre of mass (no tipping moment from the push itself):

    push direction d (unit, horizontal), speed s, lateral offset e of the line of push from the COM
    (along n = d rotated +90 deg about z):
        impulse J = m s d                                (m: the given mass, or the estimate below)
        contact point c = com + s_in d + e n             (s_in < 0: where the line of push enters the section)
        lin_vel v = J / m = s d
        ang_vel w = I^-1 (r x J) = -s e (I/m)^-1 z       (r = c - com; n x d = -z; the mass cancels)
    |e| is bounded by the section's extent across d (support function), so every planned velocity pair is
    producible by one contact: the spin of a push is tied to its speed and where it hits.

Where the numbers come from:
* from a cloud (preferred): the solid convex hull of the observed points (open3d's qhull, via
  physdyn_ros.shapes). COM = the hull's centroid, inertia per unit mass = the hull's (exact for convex objects;
  for concave ones, a mug, the hull slightly overestimates the radius of gyration), mass = hull volume *
  density (the simulator's density by default; pass the real mass when it is known, it only scales J).
  The section is the hull cut by the plane z = COM height (a convex polygon).
* from a ShapeCode only (a perception node's shape feature, no points): a solid box with the code's half
  extents, rotated by its heading, centred at its centroid. Cruder, documented as such in the plan's `body`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import geometry as geo
from ..shapes.core import DEFAULT_DENSITY, convex_hull, mass_properties


class BodyError(ValueError):
    """The points or the shape code do not describe a solid that can be pushed."""


@dataclass(frozen=True)
class PushBody:
    """Mass properties and COM-height cross-section, table-frame axes, of the object as observed."""

    com: np.ndarray  # (3,) m, centre of mass in the table frame (at the observed pose)
    mass: float  # kg, estimate (volume * density) unless given
    inertia_per_mass: np.ndarray  # (3, 3) m^2, inertia about the COM / mass, table axes
    section: np.ndarray  # (K, 2) m, CCW convex polygon at COM height, relative to the COM (x, y)
    source: str  # "hull" (from points) or "box" (from a shape code's half extents)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass) and self.mass > 0):
            raise BodyError(f"mass must be positive and finite, got {self.mass}")
        if len(self.section) < 3:
            raise BodyError("the cross-section at COM height has fewer than 3 corners")

    # -------------------------------------------------------------------------------------------- queries
    def lever_limits(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Largest offsets (>= 0) of a line of push from the COM, to the +n and to the -n side, for (B, 2)
        unit directions d (n = d rotated +90 deg)."""
        n = np.stack([-directions[:, 1], directions[:, 0]], axis=1)
        proj = n @ self.section.T  # (B, K)
        return np.maximum(proj.max(axis=1), 0.0), np.maximum(-proj.min(axis=1), 0.0)

    def offsets(self, directions: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        """Signed lateral offsets e (m) for fractions in [-1, 1] of the lever limit on that side."""
        pos, neg = self.lever_limits(directions)
        return np.where(fractions >= 0, fractions * pos, fractions * neg)

    def angular_velocity(self, speeds: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """(B, 3) angular velocity right after a horizontal push of speed s whose line passes e from the COM."""
        col = np.linalg.solve(self.inertia_per_mass, np.array([0.0, 0.0, 1.0]))
        return -(speeds * offsets)[:, None] * col[None, :]

    def contact_points(self, directions: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """(B, 3) points in the table frame where lines of push (direction d, offset e) enter the section.

        Lines that miss the section (offset beyond the lever limit: only from rounding) are moved onto its
        extreme point across d.
        """
        d = np.asarray(directions, dtype=np.float64)
        n = np.stack([-d[:, 1], d[:, 0]], axis=1)
        pos, neg = self.lever_limits(d)
        e = np.clip(offsets, -neg, pos)
        v = self.section
        edge = np.roll(v, -1, axis=0) - v  # (K, 2) CCW edges
        # inside iff cross(edge_k, p - v_k) >= 0 for all k, with p = e n + s d: a_k + b_k s >= 0
        base = e[:, None, None] * n[:, None, :] - v[None]  # (B, K, 2)
        a = edge[None, :, 0] * base[..., 1] - edge[None, :, 1] * base[..., 0]
        b = edge[None, :, 0] * d[:, None, 1] - edge[None, :, 1] * d[:, None, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = np.where(b > 1e-12, -a / b, -np.inf)
        s_in = lower.max(axis=1)
        s_in = np.where(np.isfinite(s_in), s_in, 0.0)
        xy = e[:, None] * n + s_in[:, None] * d
        return np.concatenate([xy + self.com[None, :2], np.full((len(d), 1), self.com[2])], axis=1)

    def radius(self) -> float:
        """Largest horizontal distance of the section from the COM (m)."""
        return float(np.linalg.norm(self.section, axis=1).max())


# --------------------------------------------------------------------------------------------- construction
def _cross2(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _hull_2d(points: np.ndarray) -> np.ndarray:
    """Convex hull (CCW, no repeated first point) of 2D points, Andrew's monotone chain."""
    pts = np.unique(np.round(points, 12), axis=0)
    if len(pts) < 3:
        return pts
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def half(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and _cross2(out[-1] - out[-2], p - out[-2]) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _section(vertices: np.ndarray, faces: np.ndarray, z: float) -> np.ndarray:
    """Polygon (K, 2) of a convex mesh cut by the plane at height z (the projection if the cut is degenerate)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    da, db = a[:, 2] - z, b[:, 2] - z
    cross = (da * db) < 0
    t = da[cross] / (da[cross] - db[cross])
    pts = a[cross, :2] + t[:, None] * (b[cross, :2] - a[cross, :2])
    on = np.abs(vertices[:, 2] - z) < 1e-9
    poly = _hull_2d(np.concatenate([pts, vertices[on, :2]]))
    if len(poly) < 3:
        poly = _hull_2d(vertices[:, :2])
    return poly


def body_from_cloud(cloud: np.ndarray, density: float = DEFAULT_DENSITY, mass: float | None = None) -> PushBody:
    """PushBody of the solid convex hull of an observed cloud (N, 3) in the table frame."""
    pts = np.asarray(cloud, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 4:
        raise BodyError(f"need an (N >= 4, 3) cloud to estimate the body, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise BodyError("cloud contains NaN or inf")
    try:
        v, f = convex_hull(pts)
        mp = mass_properties(v, f, density=density)
    except ValueError as exc:
        raise BodyError(f"cloud does not enclose a solid: {exc}") from None
    com = mp.com
    section = _section(v, f, float(com[2])) - com[:2]
    m = mp.mass if mass is None else float(mass)
    return PushBody(com=com, mass=m, inertia_per_mass=mp.inertia / mp.mass, section=section, source="hull")


def body_from_box(centroid: np.ndarray, half_extents: np.ndarray, heading: float,
                  density: float = DEFAULT_DENSITY, mass: float | None = None) -> PushBody:
    """PushBody of a solid box (half extents in a frame rotated by `heading` about z) centred at `centroid`."""
    h = np.asarray(half_extents, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise BodyError(f"half extents must be positive, got {h.tolist()}")
    a, b, c = h
    local = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) / 3.0
    rot = geo.yaw_matrix(float(heading))
    corners = np.array([[a, b], [-a, b], [-a, -b], [a, -b]])
    section = _hull_2d(corners @ rot[:2, :2].T)
    m = 8.0 * a * b * c * density if mass is None else float(mass)
    return PushBody(com=np.asarray(centroid, dtype=np.float64).reshape(3), mass=m,
                    inertia_per_mass=rot @ local @ rot.T, section=section, source="box")
