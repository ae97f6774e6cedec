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
"""A broad training world: procedural shape families beyond the paper's six categories.

Every family is a parametric generator drawn from a shape seed (like the paper's categories of `paper.py`, which
stay as they are): wide continuous parameter ranges at tabletop sizes (largest extent about 4-40 cm), so each family
yields as many distinct shapes as seeds. Shapes are closed, outward meshes with z up, resting upright on a face
of their convex hull with the centre of mass over the support polygon, re-centred on the centre of mass by
`make_shape`. Mass and inertia come from the mesh at uniform density, as for every shape.

Convex families are single convex hulls. The others are built from convex pieces (`Shape.parts`): the mesh is
the boundary of their union (`solids.union_surface`; pieces touch face to face or overlap, overlaps count once
in the mass properties) and the simulator uses the pieces as an exact compound collision shape.

`FAMILY_CATALOGUE` lists every category, the paper's six included, with its group; `FAMILIES` the new ones;
`HELD_OUT_FAMILIES` the families config/generate_broad.yaml keeps out of training (the held-out-family test).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .core import Shape, convex_hull, make_shape, mass_properties
from .paper import CATEGORIES, lathe, shape_seed
from .solids import (box_points, ellipsoid_points, flat_phase, frustum_points, lathe_sections, polygon,
                     rest_on_stable_face, rotate_to_axis, support_margin, union_surface)

#: Largest extent of every new family's shapes, m (the generator's per-axis scale 0.5-1.5 and its clip to
#: 4-45 cm come on top, per simulation).
SIZE_RANGE: tuple[float, float] = (0.04, 0.40)

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Family:
    """One catalogue entry: a category name, its group, whether it is one convex hull, what it is."""

    name: str
    group: str
    convex: bool
    description: str


@dataclass
class _Built:
    vertices: np.ndarray
    faces: np.ndarray
    params: dict
    parts: list[np.ndarray] | None = None


def _r(x) -> float | list:
    a = np.asarray(x, dtype=np.float64)
    return round(float(a), 5) if a.ndim == 0 else np.round(a, 5).tolist()


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _convex(points: np.ndarray, params: dict) -> _Built:
    v, f = convex_hull(points)
    return _Built(v, f, params)


def _pieces(pieces: list[np.ndarray], params: dict) -> _Built:
    """A solid made of convex pieces: the union's surface, and the pieces' hull vertices as parts."""
    hulls = [convex_hull(p)[0] for p in pieces]
    v, f = union_surface(hulls)
    return _Built(v, f, params, hulls)


def _com(built: _Built) -> np.ndarray:
    return mass_properties(built.vertices, built.faces, density=1.0).com


def _rest(built: _Built, within: float | None = None) -> _Built:
    """Rotate the solid onto its most stable hull face (rocks, polyhedra, unbalanced compositions); `within`: among
    the faces tilted at most that much (rad) from its bottom (rest_on_stable_face)."""
    rot, _ = rest_on_stable_face(built.vertices, built.faces, within)
    built.vertices = built.vertices @ rot.T
    if built.parts is not None:
        built.parts = [p @ rot.T for p in built.parts]
    return built


def _fit(built: _Built, rng: np.random.Generator | None = None) -> _Built:
    """Scale uniformly down so the largest extent is at most SIZE_RANGE[1] (recorded in params)."""
    ext = float(np.ptp(built.vertices, axis=0).max())
    if ext > SIZE_RANGE[1]:
        k = SIZE_RANGE[1] / ext
        built.vertices = built.vertices * k
        if built.parts is not None:
            built.parts = [p * k for p in built.parts]
        built.params["fit_scale"] = _r(k)
    return built


# ------------------------------------------------------------------------------------------- convex families
def _superellipsoid(rng: np.random.Generator) -> _Built:
    # Rounded boxes (small exponents), ellipsoids (1), pillows, diamonds / octahedra (near 2); a flat base cut,
    # sometimes a flat top (domes, lentils). Exponents <= 1.9 keep it convex.
    a = _logu(rng, 0.02, 0.15)
    b = float(np.clip(a * _logu(rng, 0.5, 2.0), 0.02, 0.16))
    c = _logu(rng, 0.02, 0.15)
    e1, e2 = rng.uniform(0.1, 1.9, 2)
    pts = ellipsoid_points((a, b, c), 16, 28, (e1, e2))
    bottom = rng.uniform(0.15, 0.5)  # fraction of c cut off at the bottom (flat base)
    top = rng.uniform(0.1, 0.6) if rng.random() < 0.3 else 0.0
    pts[:, 2] = np.clip(pts[:, 2], -c * (1 - bottom), c * (1 - top))
    return _convex(pts, {"radii": _r([a, b, c]), "exponents": _r([e1, e2]), "cut_bottom": _r(bottom),
                         "cut_top": _r(top)})


def _capsule(rng: np.random.Generator) -> _Built:
    # Hull of 2-4 spheres: pills / capsules, lozenges, rounded triangles and rectangles lying flat (squashed
    # vertically), or a capsule standing on a flattened end.
    kind = str(rng.choice(["capsule", "lozenge", "triangle", "rectangle", "upright"], p=[.3, .2, .15, .15, .2]))
    r = _logu(rng, 0.018, 0.06)
    if kind == "upright":
        length = min(rng.uniform(1.0, 4.0) * r, 0.36 - 2 * r)
        centres = np.array([[0, 0, -length / 2], [0, 0, length / 2]])
        squash = 1.0
    else:
        span = min(rng.uniform(0.6, 5.0) * r, 0.38 - 2 * r)
        span2 = span * rng.uniform(0.3, 1.0)
        if kind == "capsule":
            centres = np.array([[-span / 2, 0, 0], [span / 2, 0, 0]])
        elif kind == "lozenge":
            centres = np.array([[-span / 2, 0, 0], [span / 2, 0, 0], [0, -span2 / 2, 0], [0, span2 / 2, 0]])
        elif kind == "triangle":
            ang = np.pi / 2 + 2 * np.pi * np.arange(3) / 3 + rng.uniform(-0.3, 0.3, 3)
            centres = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(3)]) * span / 2
        else:
            centres = np.array([[x, y, 0] for x in (-span / 2, span / 2) for y in (-span2 / 2, span2 / 2)])
        squash = rng.uniform(0.45, 1.0)
    ball = ellipsoid_points((r, r, r), 10, 20)
    pts = np.vstack([ball + c for c in centres])
    pts[:, 2] *= squash
    cut = rng.uniform(0.15, 0.45)  # of the vertical radius, flat base
    zmin = pts[:, 2].min()
    pts[:, 2] = np.maximum(pts[:, 2], zmin + cut * r * squash)
    return _convex(pts, {"kind": kind, "radius": _r(r), "centres": _r(centres), "squash": _r(squash),
                         "cut_bottom": _r(cut)})


def _prism(rng: np.random.Generator) -> _Built:
    # n-gon prisms and antiprisms, 3-12 sides, regular or irregular, stretched, optionally tapered (frustums).
    n = int(rng.integers(3, 13))
    radius = _logu(rng, 0.025, 0.15)
    height = _logu(rng, 0.02, 0.35)
    stretch = rng.uniform(0.55, 1.0) if rng.random() < 0.4 else 1.0
    jitter = rng.uniform(0.0, 0.3) if rng.random() < 0.3 else 0.0
    taper = rng.uniform(0.5, 1.0) if rng.random() < 0.4 else 1.0
    anti = bool(rng.random() < 0.35)
    ang = 2 * np.pi * np.arange(n) / n
    rad = radius * (1 - jitter * rng.random(n))
    base = np.column_stack([rad * np.cos(ang), stretch * rad * np.sin(ang)])
    if anti:
        ang2 = ang + np.pi / n
        rad2 = radius * (1 - jitter * rng.random(n))
        top = np.column_stack([rad2 * np.cos(ang2), stretch * rad2 * np.sin(ang2)]) * taper
    else:
        top = base * taper
    return _convex(frustum_points(base, 0.0, top, height),
                   {"sides": n, "radius": _r(radius), "height": _r(height), "stretch": _r(stretch),
                    "jitter": _r(jitter), "taper": _r(taper), "antiprism": anti})


def _pyramid(rng: np.random.Generator) -> _Built:
    # Pyramids and cones (apex), frustums, inverted frustums; optionally oblique (apex off-centre), stretched.
    n = int(rng.choice([3, 4, 5, 6, 8, 40]))
    radius = _logu(rng, 0.03, 0.15)
    height = _logu(rng, 0.03, 0.3)
    u = rng.random()
    kind = "apex" if u < 0.45 else ("frustum" if u < 0.85 else "inverted")
    ratio = {"apex": 0.0, "frustum": rng.uniform(0.15, 0.75), "inverted": rng.uniform(1.25, 2.0)}[kind]
    stretch = rng.uniform(0.6, 1.0) if rng.random() < 0.3 else 1.0
    r_base = radius / ratio if kind == "inverted" else radius
    offset = rng.uniform(0.0, 0.5, 2) * r_base * (rng.random() < 0.3) * (kind != "inverted")
    section = polygon(n, 1.0) * np.array([1.0, stretch])
    top = section * r_base * ratio + offset if ratio > 0 else offset[None, :]
    return _convex(frustum_points(section * r_base, 0.0, top, height),
                   {"sides": n, "base_radius": _r(r_base), "height": _r(height), "kind": kind,
                    "top_ratio": _r(ratio), "stretch": _r(stretch), "apex_offset": _r(offset)})


def _wedge(rng: np.random.Generator) -> _Built:
    # Ramps / doorstops (triangular or trapezoidal prisms lying on their long face, optional front lip and
    # narrower front) and cheese wedges (circular sectors lying flat).
    if rng.random() < 0.3:
        angle = np.radians(rng.uniform(25, 100))
        radius = _logu(rng, 0.06, 0.2)
        thick = _logu(rng, 0.02, 0.12)
        a = np.linspace(-angle / 2, angle / 2, 12)
        sector = np.vstack([[0.0, 0.0], radius * np.column_stack([np.cos(a), np.sin(a)])])
        return _convex(frustum_points(sector, 0.0, sector, thick),
                       {"kind": "sector", "angle_deg": _r(np.degrees(angle)), "radius": _r(radius),
                        "thickness": _r(thick)})
    length = _logu(rng, 0.06, 0.35)
    width = _logu(rng, 0.04, 0.3)
    height = min(_logu(rng, 0.02, 0.2), length)
    top = rng.uniform(0.0, 0.5) * length if rng.random() < 0.5 else 0.0
    lip = rng.uniform(0.05, 0.35) * height if rng.random() < 0.4 else 0.0
    front = rng.uniform(0.5, 1.0) if rng.random() < 0.25 else 1.0
    prof = [(0.0, 0.0), (length, 0.0), (0.0, height)] + ([(top, height)] if top else []) + \
           ([(length, lip)] if lip else [])
    pts = []
    for x, z in prof:
        w = width * (1 - (1 - front) * x / length)
        pts += [[x, -w / 2, z], [x, w / 2, z]]
    return _convex(np.asarray(pts), {"kind": "ramp", "length": _r(length), "width": _r(width),
                                     "height": _r(height), "top": _r(top), "lip": _r(lip),
                                     "front_width": _r(front)})


_PHI = (1 + 5 ** 0.5) / 2


def _perms(v) -> np.ndarray:
    """All sign changes and cyclic / all permutations of a coordinate triple, unique."""
    import itertools

    out = set()
    for perm in itertools.permutations(v):
        for signs in itertools.product((-1, 1), repeat=3):
            out.add(tuple(float(s * p) for s, p in zip(signs, perm)))
    return np.asarray(sorted(out))


def _solid(name: str) -> np.ndarray:
    if name == "tetrahedron":
        return np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    if name == "octahedron":
        return _perms((1, 0, 0))
    if name == "dodecahedron":
        return np.vstack([_perms((1, 1, 1)), *[np.roll(p, k, axis=1) for k in range(3)
                                               for p in [np.array([[0, s / _PHI, t * _PHI] for s in (-1, 1)
                                                                   for t in (-1, 1)])]]])
    if name == "icosahedron":
        return np.vstack([np.roll(np.array([[0, s, t * _PHI] for s in (-1, 1) for t in (-1, 1)], float), k, axis=1)
                          for k in range(3)])
    if name == "cuboctahedron":
        return _perms((1, 1, 0))
    if name == "truncated_octahedron":
        return _perms((0, 1, 2))
    if name == "rhombic_dodecahedron":
        return np.vstack([_perms((1, 1, 1)), _perms((2, 0, 0))])
    if name.startswith("bipyramid"):
        n = int(name[-1])
        return np.vstack([np.column_stack([polygon(n, 1.0), np.zeros(n)]), [[0, 0, 1.0], [0, 0, -1.0]]])
    raise ValueError(name)


POLYHEDRA = ("tetrahedron", "octahedron", "dodecahedron", "icosahedron", "cuboctahedron", "truncated_octahedron",
             "rhombic_dodecahedron", "bipyramid3", "bipyramid4", "bipyramid5", "bipyramid6")


def _polyhedron(rng: np.random.Generator) -> _Built:
    # Platonic / Archimedean / Catalan solids and bipyramids, randomly rotated and stretched per axis (general
    # affine images), resting on their most stable face.
    name = str(rng.choice(POLYHEDRA))
    pts = _solid(name)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    stretch = rng.uniform(0.6, 1.6, 3)
    pts = (pts @ q.T) * stretch
    size = _logu(rng, 0.05, 0.3)
    pts *= size / np.ptp(pts, axis=0).max()
    return _rest(_convex(pts, {"solid": name, "stretch": _r(stretch), "size": _r(size)}))


def _rock(rng: np.random.Generator) -> _Built:
    # Convex hulls of random point sets in an ellipsoid: angular stones (points inside, few vertices) or
    # smooth pebbles (points on the surface), resting on their most stable face.
    radii = np.array([_logu(rng, 0.02, 0.14) for _ in range(3)])
    smooth = bool(rng.random() < 0.5)
    n = int(rng.integers(20, 61) if smooth else rng.integers(6, 25))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rad = np.ones(n) if smooth else rng.random(n) ** (1 / 3) * 0.5 + 0.5
    pts = d * rad[:, None] * radii
    return _rest(_convex(pts, {"radii": _r(radii), "points": n, "smooth": smooth}))


# -------------------------------------------------------------------------------------- families of pieces
def _vase(rng: np.random.Generator) -> _Built:
    # Solids of revolution with a random smooth profile (vases, jars, goblets, barrels, hourglasses, spinning
    # tops with a flat foot), round or polygonal; pieces: the frustums between consecutive rings.
    height = _logu(rng, 0.08, 0.36)
    r_max = rng.uniform(0.025, 0.11)
    k = int(rng.integers(3, 7))
    ctrl = r_max * rng.uniform(0.3, 1.0, k)
    ctrl[int(rng.integers(0, k))] = r_max
    ctrl[0] = max(ctrl[0], 0.35 * r_max)  # a foot wide enough to stand on
    rings = int(rng.integers(10, 15))
    t = np.linspace(0, 1, rings)
    tk = np.linspace(0, 1, k)
    j = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, k - 2)
    s = (t - tk[j]) / (tk[j + 1] - tk[j])
    radii = ctrl[j] + (ctrl[j + 1] - ctrl[j]) * s * s * (3 - 2 * s)  # smoothstep between control radii
    heights = t * height
    segments = int(rng.choice([6, 8, 12, 24, 32]))
    phase = flat_phase(segments, 0.0)
    prof = np.vstack([[0.0, 0.0], np.column_stack([radii, heights]), [0.0, height]])
    v, f = lathe(prof, segments, phase)
    return _Built(v, f, {"height": _r(height), "control_radii": _r(ctrl), "segments": segments},
                  lathe_sections(radii, heights, segments, phase))


def _boxes_com(boxes: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    vol = np.array([np.prod(hi - lo) for lo, hi in boxes])
    return (np.array([(lo + hi) / 2 for lo, hi in boxes]) * vol[:, None]).sum(0) / vol.sum()


_LETTERS = ("L", "T", "U", "H", "plus")


def _letter_rects(letter: str, w: float, h: float, s: float, s2: float, cy: float) -> list[tuple]:
    """Non-overlapping rectangles (u0, w0, u1, w1) of a block letter of width w, height h, strokes s (vertical)
    and s2 (horizontal); cy: height of H's bar (fraction)."""
    if letter == "L":
        return [(0, 0, s, h), (s, 0, w, s2)]
    if letter == "T":
        return [(0, h - s2, w, h), ((w - s) / 2, 0, (w + s) / 2, h - s2)]
    if letter == "U":
        return [(0, 0, w, s2), (0, s2, s, h), (w - s, s2, w, h)]
    if letter == "H":
        z = cy * (h - s2)
        return [(0, 0, s, h), (w - s, 0, w, h), (s, z, w - s, z + s2)]
    z = (h - s2) / 2
    return [(0, z, w, z + s2), ((w - s) / 2, 0, (w + s) / 2, z), ((w - s) / 2, z + s2, (w + s) / 2, h)]


def _letter(rng: np.random.Generator) -> _Built:
    # Block letters L, T, U, H, + made of boxes, lying flat or standing in one of four 90-degree turns (an L on
    # its foot or its leg, an upside-down T, a U or an arch, an H or an I-beam) when that stands stably.
    letter = str(rng.choice(_LETTERS))
    s = _logu(rng, 0.015, 0.06)
    s2 = s * rng.uniform(0.7, 1.4)
    w = rng.uniform(3.0, 8.0) * max(s, s2)
    h = rng.uniform(3.0, 8.0) * max(s, s2)
    w, h = min(w, 0.38), min(h, 0.38)
    depth = _logu(rng, 0.015, 0.12)
    rects = _letter_rects(letter, w, h, s, s2, rng.uniform(0.2, 0.8))
    pose = "flat" if rng.random() < 0.4 else "upright"
    turn = 0
    boxes = [(np.array([u0, w0, 0.0]), np.array([u1, w1, depth])) for u0, w0, u1, w1 in rects]
    if pose == "upright":
        for turn in rng.permutation(4):
            c, sn = np.cos(turn * np.pi / 2), np.sin(turn * np.pi / 2)
            up = []
            for u0, w0, u1, w1 in rects:
                corners = np.array([[u0, w0], [u1, w1]]) @ np.array([[c, sn], [-sn, c]])
                lo, hi = corners.min(0), corners.max(0)
                up.append((np.array([lo[0], -depth / 2, lo[1]]), np.array([hi[0], depth / 2, hi[1]])))
            zmin = min(lo[2] for lo, _ in up)
            up = [(lo - [0, 0, zmin], hi - [0, 0, zmin]) for lo, hi in up]
            base = np.vstack([box_points(lo, hi) for lo, hi in up])
            if support_margin(base, _boxes_com(up)) > 0.25 * min(s, s2, depth):
                boxes = up
                break
        else:
            pose = "flat"
    built = _pieces([box_points(lo, hi) for lo, hi in boxes],
                    {"letter": letter, "width": _r(w), "height": _r(h), "strokes": _r([s, s2]),
                     "depth": _r(depth), "pose": pose, "turn_deg": int(turn) * 90 if pose == "upright" else 0})
    return built


def _tier(kind: str, cx: float, cy: float, z0: float, z1: float, w: float, d: float, sides: int) -> np.ndarray:
    if kind == "box":
        return box_points([cx - w / 2, cy - d / 2, z0], [cx + w / 2, cy + d / 2, z1])
    sec = polygon(sides, 0.5, flat_phase(sides, 0.0)) * np.array([w, d]) + [cx, cy]
    return frustum_points(sec, z0, sec, z1)


def _stack(rng: np.random.Generator) -> _Built:
    # 2-4 stacked tiers (boxes or n-gon discs) joined face to face: ziggurats, tiered cakes, staircases (tiers
    # flush with one side), mushrooms and pedestals (a wider tier above).
    n = int(rng.integers(2, 5))
    kind = str(rng.choice(["box", "round", "mixed"]))
    sides = int(rng.choice([6, 8, 12, 24]))
    w, d = rng.uniform(0.06, 0.3), rng.uniform(0.06, 0.3)
    stairs = bool(rng.random() < 0.35)
    z, cx, cy = 0.0, 0.0, 0.0
    tiers, pieces = [], []
    for i in range(n):
        h = _logu(rng, 0.015, 0.1)
        if z + h > 0.38:
            break
        if i:
            grow = rng.uniform(1.0, 1.4) if rng.random() < 0.2 else rng.uniform(0.45, 1.0)
            nw, nd = max(0.02, w * grow), max(0.02, d * rng.uniform(0.8, 1.2) * grow)
            if stairs and nw <= w:
                cx, cy = cx + (w - nw) / 2, cy
            else:
                cx = cx + rng.uniform(-0.3, 0.3) * abs(w - nw) / 2
                cy = cy + rng.uniform(-0.3, 0.3) * abs(d - nd) / 2
            w, d = min(nw, 0.38), min(nd, 0.38)
        tk = kind if kind != "mixed" else str(rng.choice(["box", "round"]))
        pieces.append(_tier(tk, cx, cy, z, z + h, w, d, sides))
        tiers.append({"kind": tk, "centre": _r([cx, cy]), "size": _r([w, d, h])})
        z += h
    built = _pieces(pieces, {"tiers": tiers, "stairs": stairs})
    if support_margin(built.vertices, _com(built)) <= 0:
        built = _rest(built)
    return built


def _ring(rng: np.random.Generator) -> _Built:
    # Torus-like rings lying flat: k convex segments around a circle (or an oval), section a rectangle (washers,
    # square / hexagonal frames when k is 4 or 6) or a hexagon / octagon (torus-like); segments touch face to face.
    k = int(rng.choice([4, 6])) if rng.random() < 0.2 else int(rng.integers(8, 21))
    mean_r = rng.uniform(0.04, 0.16)
    width = min(max(0.01, rng.uniform(0.12, 0.9) * mean_r), 2 * (0.195 - mean_r))
    height = _logu(rng, 0.012, 0.08)
    m = int(rng.choice([4, 6, 8]))
    oval = rng.uniform(0.7, 1.0) if rng.random() < 0.3 else 1.0
    sec = polygon(m, 1.0, flat_phase(m, -np.pi / 2))
    sec = (sec - sec.min(0)) / np.ptp(sec, axis=0)  # unit square box [0, 1]^2, flat bottom
    r = mean_r - width / 2 + width * sec[:, 0]
    zs = height * sec[:, 1]
    th = 2 * np.pi * np.arange(k + 1) / k
    sections = [np.column_stack([oval * r * np.cos(a), r * np.sin(a), zs]) for a in th]
    return _pieces([np.vstack([sections[i], sections[i + 1]]) for i in range(k)],
                   {"segments": k, "mean_radius": _r(mean_r), "width": _r(width), "height": _r(height),
                    "section_sides": m, "oval": _r(oval)})


def _dumbbell(rng: np.random.Generator) -> _Built:
    # A bar between two weights lying on their rims: n-gon discs (optionally two plates a side), square plates or
    # balls with a flat spot; sometimes unequal weights (the solid then rests on its most stable face).
    kind = str(rng.choice(["disc", "plates", "square", "ball"], p=[.4, .2, .2, .2]))
    R = rng.uniform(0.02, 0.07)
    t = rng.uniform(0.012, 0.06)
    bar_r = max(0.005, rng.uniform(0.2, 0.5) * R)
    bar_len = rng.uniform(0.04, 0.22)
    n = int(rng.choice([6, 8, 10, 12, 16, 24]))
    ratio = rng.uniform(0.6, 0.95) if rng.random() < 0.25 else 1.0
    bar = frustum_points(polygon(8, bar_r, flat_phase(8, 0.0)), -bar_len / 2, polygon(8, bar_r, flat_phase(8, 0.0)),
                         bar_len / 2)
    pieces = [rotate_to_axis(bar, "x")]
    for side, k in ((-1, 1.0), (1, ratio)):
        x0 = bar_len / 2
        if kind in ("disc", "plates"):
            plates = [(R * k, t)] + ([(R * k * rng.uniform(0.6, 0.9), t * rng.uniform(0.5, 1.0))]
                                     if kind == "plates" else [])
            for rad, th in plates:
                sec = polygon(n, rad, flat_phase(n, 0.0))
                pieces.append(rotate_to_axis(frustum_points(sec, x0, sec, x0 + th), "x") * [side, 1, 1])
                x0 += th
        elif kind == "square":
            h = R * k
            pieces.append(box_points([x0, -h, -h], [x0 + t, h, h]) * [side, 1, 1])
        else:
            rad = R * k
            ball = ellipsoid_points((rad, rad, rad), 10, 20)
            ball[:, 2] = np.maximum(ball[:, 2], -0.9 * rad)  # flat spot to rest on
            pieces.append((ball + [x0 + rng.uniform(0.6, 0.85) * rad, 0, 0]) * [side, 1, 1])
    built = _pieces(pieces, {"kind": kind, "weight_radius": _r(R), "weight_thickness": _r(t), "sides": n,
                             "bar_radius": _r(bar_r), "bar_length": _r(bar_len), "ratio": _r(ratio)})
    return _rest(built) if ratio != 1.0 else built


def _primitive(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    """A random convex primitive centred at 0: box, n-gon cylinder (axis x, y or z) or ellipsoid."""
    kind = str(rng.choice(["box", "cylinder", "ellipsoid"], p=[.45, .35, .2]))
    if kind == "box":
        return kind, box_points(*(np.array([-1, 1])[:, None] * [_logu(rng, 0.01, 0.08) for _ in range(3)]))
    if kind == "cylinder":
        n = int(rng.choice([6, 8, 12, 24]))
        r, h = _logu(rng, 0.01, 0.07), _logu(rng, 0.02, 0.16)
        sec = polygon(n, r, flat_phase(n, 0.0))
        return kind, rotate_to_axis(frustum_points(sec, -h / 2, sec, h / 2), str(rng.choice(["x", "y", "z"])))
    return kind, ellipsoid_points([_logu(rng, 0.012, 0.07) for _ in range(3)], 8, 16)


def _composite(rng: np.random.Generator) -> _Built:
    # 2-5 random convex primitives (boxes, cylinders, ellipsoids) attached one by one to the top or a side of
    # an earlier one: face to face for two boxes, else sunk in by 10-35 % of the new piece's half size so the
    # pieces overlap (the union counts the overlap once). Unbalanced results rest on their most stable face.
    n = int(rng.integers(2, 6))
    kinds, pieces = [], []
    kind, p = _primitive(rng)
    pieces.append(p - [0, 0, p[:, 2].min()])
    kinds.append(kind)
    attach = []
    for _ in range(1, n):
        kind, p = _primitive(rng)
        j = int(rng.integers(0, len(pieces)))
        lo, hi = pieces[j].min(0), pieces[j].max(0)
        plo, phi = p.min(0), p.max(0)
        face = str(rng.choice(["top", "+x", "-x", "+y", "-y"], p=[.4, .15, .15, .15, .15]))
        flush = kind == "box" and kinds[j] == "box" and rng.random() < 0.6
        axis = 2 if face == "top" else (0 if face[1] == "x" else 1)
        sink = 0.0 if flush else rng.uniform(0.1, 0.35) * (phi[axis] - plo[axis]) / 2
        centre = lo + (hi - lo) * rng.uniform(0.2, 0.8, 3)
        if face == "top":
            centre[2] = hi[2] - sink - plo[2]
        elif face[0] == "+":
            centre[axis] = hi[axis] - sink - plo[axis]
        else:
            centre[axis] = lo[axis] + sink - phi[axis]
        q = p + centre
        q[:, 2] -= min(q[:, 2].min(), 0.0)  # nothing below the table
        pieces.append(q)
        kinds.append(kind)
        attach.append({"kind": kind, "to": j, "face": face, "flush": bool(flush)})
    built = _pieces(pieces, {"base": kinds[0], "attached": attach})
    if support_margin(built.vertices, _com(built)) <= 0.1 * (built.vertices[:, 2].max() - built.vertices[:, 2].min()):
        built = _rest(built)
    return _fit(built)


def _legged(rng: np.random.Generator) -> _Built:
    # Tables, stools and benches: a top (rectangular or n-gon slab) on 4 or 3 legs (square or n-gon posts), two
    # panels (bench), or a column on a foot (pedestal); legs meet the top face to face.
    kind = str(rng.choice(["four", "three", "panels", "pedestal"], p=[.35, .25, .2, .2]))
    round_top = kind in ("three", "pedestal") or rng.random() < 0.25
    top_t = _logu(rng, 0.008, 0.04)
    leg_h = _logu(rng, 0.03, 0.3)
    if round_top:
        sides = int(rng.choice([8, 12, 24]))
        rad = rng.uniform(0.04, 0.17)
        w = d = 2 * rad
        sec = polygon(sides, rad, flat_phase(sides, 0.0))
        top = frustum_points(sec, leg_h, sec, leg_h + top_t)
    else:
        sides = 0
        w, d = rng.uniform(0.08, 0.35), rng.uniform(0.06, 0.3)
        top = box_points([-w / 2, -d / 2, leg_h], [w / 2, d / 2, leg_h + top_t])
    leg = min(rng.uniform(0.008, 0.035), 0.2 * min(w, d))
    inset = rng.uniform(0.0, 0.2)
    square = bool(rng.random() < 0.5)
    pieces = [top]

    def post(x: float, y: float, z0: float, z1: float, r: float) -> np.ndarray:
        if square:
            return box_points([x - r, y - r, z0], [x + r, y + r, z1])
        sec = polygon(8, r, flat_phase(8, 0.0)) + [x, y]
        return frustum_points(sec, z0, sec, z1)

    if kind == "four":
        for sx in (-1, 1):
            for sy in (-1, 1):
                x = sx * (w / 2 - leg / 2 - inset * w / 2)
                y = sy * (d / 2 - leg / 2 - inset * d / 2)
                if round_top:
                    x, y = x / np.sqrt(2), y / np.sqrt(2)
                pieces.append(post(x, y, 0.0, leg_h, leg / 2))
    elif kind == "three":
        for a in 2 * np.pi * np.arange(3) / 3 + rng.uniform(0, 2 * np.pi):
            rr = (w / 2 - leg) * (1 - inset) * np.cos(np.pi / sides)
            pieces.append(post(rr * np.cos(a), rr * np.sin(a), 0.0, leg_h, leg / 2))
    elif kind == "panels":
        depth = d * rng.uniform(0.6, 1.0) / (np.sqrt(2) if round_top else 1.0)
        for sx in (-1, 1):
            x = sx * (w / 2 - leg / 2 - inset * w / 2) / (np.sqrt(2) if round_top else 1.0)
            pieces.append(box_points([x - leg / 2, -depth / 2, 0.0], [x + leg / 2, depth / 2, leg_h]))
    else:
        foot_t = min(rng.uniform(0.008, 0.03), 0.5 * leg_h)
        foot_r = rng.uniform(0.5, 0.95) * w / 2
        col_r = max(0.006, rng.uniform(0.1, 0.3) * w / 2)
        fsec = polygon(sides, foot_r, flat_phase(sides, 0.0))
        pieces.append(frustum_points(fsec, 0.0, fsec, foot_t))
        csec = polygon(8, col_r, flat_phase(8, 0.0))
        pieces.append(frustum_points(csec, foot_t, csec, leg_h))
    return _pieces(pieces, {"kind": kind, "top": "round" if round_top else "rect", "top_sides": sides,
                            "size": _r([w, d]), "top_thickness": _r(top_t), "leg_height": _r(leg_h),
                            "leg": _r(leg), "inset": _r(inset), "square_legs": square})


def _gear(rng: np.random.Generator) -> _Built:
    # Flat gears (trapezoid teeth on the edges of an n-gon hub) and stars (triangular spikes), lying flat;
    # each tooth meets the hub face to face.
    star = bool(rng.random() < 0.35)
    n = int(rng.integers(4, 10) if star else rng.integers(5, 17))
    hub = rng.uniform(0.025, 0.12)
    thick = _logu(rng, 0.012, 0.08)
    edge = 2 * hub * np.sin(np.pi / n)
    apothem = hub * np.cos(np.pi / n)
    if star:
        base, tip, length = edge, 0.0, rng.uniform(0.4, 1.3) * hub
    else:
        base = edge * rng.uniform(0.35, 0.8)
        tip = base * rng.uniform(0.4, 1.0)
        length = rng.uniform(0.12, 0.45) * hub
    length = min(length, 0.19 - hub)
    sec = polygon(n, hub)
    pieces = [frustum_points(sec, 0.0, sec, thick)]
    for i in range(n):
        mid = np.pi / n + 2 * np.pi * i / n
        u, t = np.array([np.cos(mid), np.sin(mid)]), np.array([-np.sin(mid), np.cos(mid)])
        corners = [apothem * u - base / 2 * t, apothem * u + base / 2 * t]
        corners += [(apothem + length) * u] if tip == 0 else [(apothem + length) * u + tip / 2 * t,
                                                               (apothem + length) * u - tip / 2 * t]
        outline = np.asarray(corners)
        pieces.append(frustum_points(outline, 0.0, outline, thick))
    return _pieces(pieces, {"kind": "star" if star else "gear", "teeth": n, "hub_radius": _r(hub),
                            "thickness": _r(thick), "tooth": _r([base, tip, length])})


def _roller(rng: np.random.Generator) -> _Built:
    # Solids of revolution lying on their side, which roll when pushed across their axis (no other family of
    # generate_broad2's world rests on a curved side: capsules lie on a flat, prisms and cylinders stand): n-gon
    # cylinders from a pentagon to nearly round, barrels, capsules with round ends and prolate spheroids,
    # optionally oval in section. Built along z from n-gon rings with an edge toward +x, then turned to lie along
    # x on that edge's face.
    kind = str(rng.choice(["cylinder", "barrel", "capsule", "spheroid"], p=[.35, .25, .2, .2]))
    n = int(rng.choice([5, 6, 7, 8, 10, 12, 16, 24, 40]))
    r = _logu(rng, 0.012, 0.06)
    half = 0.5 * min(rng.uniform(2.5, 8.0) * r, 0.36)  # half length of the straight part (cylinder, capsule)
    if kind == "cylinder":
        z, rad = np.array([-half, half]), np.array([r, r])
    elif kind == "barrel":
        bulge = rng.uniform(0.1, 0.4)
        z = np.linspace(-half, half, 9)
        rad = r * (1.0 + bulge * (1.0 - (z / half) ** 2))
    elif kind == "capsule":
        a = np.linspace(0.0, np.pi / 2, 6)[1:]  # hemispherical ends as 5 rings each
        cap = half + r * np.sin(a)
        z = np.concatenate([-cap[::-1], [-half, half], cap])
        rad = np.concatenate([r * np.cos(a)[::-1], [r, r], r * np.cos(a)])
    else:
        half = min(rng.uniform(1.3, 3.0) * r, 0.18)  # semi-axis along the roll axis
        t = np.linspace(-1.0, 1.0, 11)  # the tips are rings of radius 0
        z, rad = half * t, r * np.sqrt(1.0 - t * t)
    ring = polygon(n, 1.0, flat_phase(n, 0.0))  # an edge toward +x: after rotate_to_axis the bottom face
    pts = rotate_to_axis(np.vstack([np.column_stack([ring * q, np.full(n, h)]) for q, h in zip(rad, z)]), "x")
    squash = rng.uniform(0.7, 1.0) if rng.random() < 0.3 else 1.0  # oval section: rolls unevenly
    pts[:, 2] *= squash
    cut = 0.0
    if kind != "cylinder":  # curved along the axis too: a thin flat to rest on instead of one line of contact
        cut = rng.uniform(0.02, 0.08)
        pts[:, 2] = np.maximum(pts[:, 2], pts[:, 2].min() + cut * r * squash)
    length = float(np.ptp(pts[:, 0]))
    if length < SIZE_RANGE[0]:  # a short thin roller: stretched along its axis to the family's smallest size
        pts[:, 0] *= 1.001 * SIZE_RANGE[0] / length
    built = _convex(pts, {"kind": kind, "sides": n, "radius": _r(r), "length": _r(float(np.ptp(pts[:, 0]))),
                          "squash": _r(squash), "cut_bottom": _r(cut)})
    return _fit(built)  # a long capsule: scaled down to the largest size


def _tool(rng: np.random.Generator) -> _Built:
    # Handled tools lying down: a head on one end of a long thin handle (round, or a flat bar lying flat);
    # hammers (a box across the handle), pans (an n-gon disc, the handle's top level with its rim, or on the table
    # beside a thin pan), brushes (a block along the handle), ladles and mallets (a ball with a flat spot). Each
    # rests on its most stable face tilted at most 45 degrees from the pose built (never standing on the head's
    # end): on the head and the handle's end, the handle slanted, or on the head, the handle in the air.
    kind = str(rng.choice(["hammer", "pan", "brush", "ladle"]))
    length = rng.uniform(0.08, 0.3)
    hr = _logu(rng, 0.004, 0.014)
    flat = bool(rng.random() < 0.4)
    sec = (box_points([-hr * 0.7, -hr * 2.5, 0.0], [hr * 0.7, hr * 2.5, 0.0])[::2, :2] if flat
           else polygon(8, hr, flat_phase(8, 0.0)))  # built along z; rotate_to_axis turns its first axis up
    if kind == "hammer":
        hx, hy = rng.uniform(0.012, 0.035), rng.uniform(0.03, 0.09)
        hz = max(hx * rng.uniform(0.7, 1.3), 1.5 * hr)
        head = box_points([-2 * hx, -hy, 0.0], [0.0, hy, 2 * hz])
        zc, x0 = hz, -hx
    elif kind == "pan":
        rad, t = rng.uniform(0.04, 0.12), _logu(rng, 0.012, 0.05)
        length = min(length, 0.38 - 2 * rad)  # no scaling down: the pan keeps its 1.2 cm
        n = int(rng.choice([8, 12, 24]))
        disc = polygon(n, rad, flat_phase(n, 0.0)) - [rad, 0.0]
        head = frustum_points(disc, 0.0, disc, t)
        half = 0.7 * hr if flat else hr  # the handle's half height
        zc, x0 = max(t - half, half), -0.1 * rad
    elif kind == "brush":
        bl, bw, bh = rng.uniform(0.04, 0.12), rng.uniform(0.02, 0.06), rng.uniform(0.015, 0.05)
        head = box_points([-bl, -bw / 2, 0.0], [0.0, bw / 2, bh])
        zc, x0 = max(bh * rng.uniform(0.4, 0.8), hr), -0.1 * bl
    else:
        rad = rng.uniform(0.02, 0.06)
        head = ellipsoid_points((rad, rad, rad), 10, 20) + [-rad, 0.0, rad]
        head[:, 2] = np.maximum(head[:, 2], 0.1 * rad)
        zc, x0 = rad, -0.3 * rad
    handle = rotate_to_axis(frustum_points(sec, 0.0, sec, length), "x") + [x0, 0.0, zc]
    built = _pieces([head, handle], {"kind": kind, "handle_length": _r(length), "handle_radius": _r(hr),
                                     "flat_handle": flat})
    return _fit(_rest(built, within=np.radians(45.0)))


def _topheavy(rng: np.random.Generator) -> _Built:
    # Upright objects heavy above a narrow base: lamps, trophies, solid goblets, signs on a post; a foot (n-gon
    # disc), a thin stem and a bulky top 0.6-2.2 foot radii across (a block about as tall as it is wide, a ball,
    # an inverted cone or a shade); blocks, balls and shades sometimes off the stem's axis, the centre of mass
    # still over the foot. Thin slabs on a column are the held-out legged family's.
    n = int(rng.choice([6, 8, 12, 24]))
    foot_r, foot_t = rng.uniform(0.02, 0.07), _logu(rng, 0.005, 0.025)
    stem_r = max(0.004, rng.uniform(0.1, 0.45) * foot_r)
    stem_h = _logu(rng, 0.03, 0.22)
    kind = str(rng.choice(["block", "ball", "cone", "shade"]))
    size = min(rng.uniform(1.0, 2.2) * foot_r, 0.12)
    off = rng.random() < 0.3 and kind != "cone"  # a cone's narrow end stays on the stem
    shift = rng.uniform(0.0, 0.6) * foot_r * np.array([1.0, 0.0]) if off else np.zeros(2)
    z1 = foot_t + stem_h
    wide, narrow = polygon(n, size, flat_phase(n, 0.0)), polygon(n, 1.2 * stem_r, flat_phase(n, 0.0))
    if kind == "block":
        hx, hy = size * rng.uniform(0.6, 1.0), size * rng.uniform(0.3, 1.0)
        top = box_points([-hx, -hy, z1], [hx, hy, z1 + 2 * max(hx, hy) * rng.uniform(0.6, 1.5)])
    elif kind == "ball":
        rad = size * rng.uniform(0.6, 1.0)
        top = ellipsoid_points((rad, rad, rad * rng.uniform(0.7, 1.2)), 10, 20)
        top = top + [0.0, 0.0, z1 - top[:, 2].min() - 0.2 * rad]
    elif kind == "cone":
        top = frustum_points(narrow, z1, wide, z1 + size * rng.uniform(0.8, 2.0))
    else:
        top = frustum_points(wide, z1, wide * rng.uniform(0.4, 0.8), z1 + size * rng.uniform(0.8, 2.0))
    top[:, :2] += shift
    foot = polygon(n, foot_r, flat_phase(n, 0.0))
    stem = polygon(8, stem_r, flat_phase(8, 0.0))
    built = _pieces([frustum_points(foot, 0.0, foot, foot_t), frustum_points(stem, foot_t, stem, z1), top],
                    {"kind": kind, "foot": _r([foot_r, foot_t]), "stem": _r([stem_r, stem_h]), "top": _r(size),
                     "shift": _r(float(shift[0]))})
    return _fit(built)


def _rocker(rng: np.random.Generator) -> _Built:
    # Objects resting on a curved side that rock, tip and roll: solid bowls and domes upside down (the lower cap of
    # an ellipsoid, flat side up), eggs and balls (ellipsoids, standing or lying), half-cylinders lying on their
    # round side; a small flat at the lowest point to rest on.
    kind = str(rng.choice(["dome", "egg", "half_cylinder"], p=[.4, .35, .25]))
    r = _logu(rng, 0.02, 0.12)
    if kind == "dome":
        a, b = max(r * rng.uniform(0.8, 1.25), 0.021), max(r * rng.uniform(0.8, 1.25), 0.021)
        depth = max(rng.uniform(0.3, 1.0) * r, 0.016)
        pts = ellipsoid_points((a, b, r), 14, 28)
        cut = -r + depth
        ring = np.sqrt(max(1.0 - (cut / r) ** 2, 0.0)) * polygon(28, 1.0)
        pts = np.vstack([pts[pts[:, 2] < cut], np.column_stack([ring * [a, b], np.full(28, cut)])])
    elif kind == "egg":
        pts = ellipsoid_points((r, r * rng.uniform(0.6, 1.0), r * _logu(rng, 0.6, 1.6)), 14, 28)
    else:
        n = int(rng.choice([8, 12, 24]))  # facets of the round side
        ang = np.linspace(np.pi, 2 * np.pi, n + 1)
        half = np.column_stack([np.zeros(n + 1), r * np.cos(ang), r * np.sin(ang)])
        pts = np.vstack([half, half + [max(rng.uniform(0.5, 4.0) * r, 0.015), 0.0, 0.0]])
    levels = np.unique(np.round(pts[:, 2], 9))
    cut = rng.uniform(0.01, 0.12)
    # at least the lowest ring of vertices, so that the flat is a polygon, not one vertex or one edge
    pts[:, 2] = np.maximum(pts[:, 2], max(levels[0] + cut * np.ptp(levels), levels[1]))
    return _fit(_convex(pts, {"kind": kind, "radius": _r(r), "cut_bottom": _r(cut)}))


# -------------------------------------------------------------------------------------------------- registry
_NEW: dict[str, tuple[Callable[[np.random.Generator], _Built], Family]] = {
    f.name: (b, f) for b, f in [
        (_superellipsoid, Family("superellipsoid", "rounded", True,
                                 "superellipsoids with a flat base: rounded boxes, ellipsoids, pillows, diamonds, "
                                 "domes")),
        (_capsule, Family("capsule", "rounded", True,
                          "hulls of 2-4 spheres: pills, lozenges, rounded triangles/rectangles, upright capsules")),
        (_prism, Family("prism", "prismatic", True,
                        "3-12-gon prisms and antiprisms, irregular or stretched, optionally tapered")),
        (_pyramid, Family("pyramid", "prismatic", True,
                          "pyramids and cones, frustums, inverted frustums, oblique apexes")),
        (_wedge, Family("wedge", "prismatic", True, "ramps and doorstops (with top, lip, narrower front), "
                                                    "cheese wedges")),
        (_polyhedron, Family("polyhedron", "faceted", True,
                             "Platonic/Archimedean/Catalan solids and bipyramids, stretched, on a stable face")),
        (_rock, Family("rock", "faceted", True, "convex hulls of random points: angular stones, pebbles")),
        (_vase, Family("vase", "lathe", False, "random smooth solids of revolution: vases, jars, goblets, "
                                               "hourglasses; pieces: frustums")),
        (_letter, Family("letter", "blocks", False, "block letters L, T, U, H, + of boxes, flat or standing")),
        (_stack, Family("stack", "blocks", False,
                        "2-4 stacked tiers (boxes, n-gon discs): ziggurats, cakes, stairs, mushrooms")),
        (_ring, Family("ring", "rings", False,
                       "torus-like rings and frames of 4-20 convex segments, flat, round or oval")),
        (_dumbbell, Family("dumbbell", "dumbbells", False,
                           "a bar between two weights (discs, plates, squares, balls), equal or not")),
        (_composite, Family("composite", "compositions", False,
                            "2-5 random boxes/cylinders/ellipsoids attached to tops and sides")),
        (_legged, Family("legged", "compositions", False,
                         "tables, stools, benches, pedestals: a top on 3-4 legs, panels or a column")),
        (_gear, Family("gear", "compositions", False, "flat gears (trapezoid teeth) and stars (spikes)")),
        (_roller, Family("roller", "rounded", True,
                         "lying on their side: 5-40-gon cylinders, barrels, round-ended capsules, spheroids")),
        (_tool, Family("tool", "compositions", False,
                       "handled tools lying down: hammers, pans, brushes, ladles; a head and a long thin handle")),
        (_topheavy, Family("topheavy", "compositions", False,
                           "lamps, trophies, goblets: a foot, a thin stem and a bulky top, sometimes off-axis")),
        (_rocker, Family("rocker", "rounded", True,
                         "on a curved side: upside-down domes and bowls, eggs, balls, half-cylinders")),
    ]
}

_PAPER = {"box": (True, "boxes, log-uniform sides 5-35 cm"),
          "cylinder": (True, "40-gon cylinders"),
          "bottle": (True, "solid bottles (the hull is their plane-contact geometry)"),
          "mug": (False, "open cups with a handle (V-HACD collision)"),
          "trashcan": (False, "open bins, round or polygonal, tapered (V-HACD collision)"),
          "speaker": (True, "beveled / rounded cabinets, tapered")}

#: The new families (category names), in catalogue order.
FAMILIES: tuple[str, ...] = tuple(_NEW)
#: Every procedural category: the paper's six, then the new families.
ALL_CATEGORIES: tuple[str, ...] = CATEGORIES + FAMILIES
#: Catalogue of every procedural category with its group ("paper" for the six of the paper).
FAMILY_CATALOGUE: tuple[Family, ...] = tuple(Family(c, "paper", *_PAPER[c]) for c in CATEGORIES) + \
    tuple(f for _, f in _NEW.values())
#: Families config/generate_broad.yaml keeps entirely out of training (held-out-family test): shapes unlike
#: the rest (holes, bars between weights, objects standing on legs).
HELD_OUT_FAMILIES: tuple[str, ...] = ("ring", "dumbbell", "legged")


def make_family_shape(family: str, index: int, seed: int = 0) -> Shape:
    """Shape number `index` of new family `family` for master `seed` (a pure function of its arguments)."""
    if family not in _NEW:
        raise ValueError(f"unknown shape family {family!r}; known: {', '.join(FAMILIES)}")
    if index < 0:
        raise ValueError(f"shape index must be >= 0, got {index}")
    s = shape_seed(family, index, seed)
    builder, fam = _NEW[family]
    built = builder(np.random.default_rng(s))
    v = np.asarray(built.vertices, dtype=np.float64)
    dz = v[:, 2].min()
    v = v - [0.0, 0.0, dz]
    parts = None if built.parts is None else [np.asarray(p, dtype=np.float64) - [0.0, 0.0, dz] for p in built.parts]
    return make_shape(f"{family}_{index:04d}", family, v, built.faces, fam.convex, seed=s % (2**31),
                      params=built.params, parts=parts)
