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
"""The paper's six procedural categories: box, cylinder, bottle, mug, trashcan, speaker.
(The broader world's further families live in `families.py`; `procedural.make_procedural` builds either by name.)

Every category is a parametric family: a shape seed draws continuous parameters (sizes, proportions, tapers,
wall thicknesses, profiles, bevels, polygon counts), so a category yields as many distinct shapes as seeds.
Unscaled sizes are tabletop, about 5 to 40 cm. Meshes are built closed and outward-oriented, z up, and
re-centred on their centre of mass by `make_shape`. The mesh builders (`lathe`, `tube`, `merge`) and
`shape_seed` serve the families too.
"""
from __future__ import annotations

import zlib

import numpy as np

from .core import Shape, convex_hull, make_shape

CATEGORIES: tuple[str, ...] = ("box", "cylinder", "bottle", "mug", "trashcan", "speaker")


# ----------------------------------------------------------------------------------------------- mesh builders
def lathe(profile: np.ndarray, segments: int, phase: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Revolve a (r, z) profile about z. The profile must start and end on the axis (r = 0) so the surface is
    closed; interior points need r > 0. With few segments the cross-section is a regular polygon (circumradius r).
    """
    profile = np.asarray(profile, dtype=np.float64)
    if profile[0, 0] != 0 or profile[-1, 0] != 0 or np.any(profile[1:-1, 0] <= 0):
        raise ValueError("lathe profile must start and end at r = 0 with r > 0 in between")
    ang = phase + 2 * np.pi * np.arange(segments) / segments
    cos, sin = np.cos(ang), np.sin(ang)
    verts = [[0.0, 0.0, profile[0, 1]]]
    rings = []
    for r, z in profile[1:-1]:
        rings.append(len(verts) + np.arange(segments))
        verts.extend(np.stack([r * cos, r * sin, np.full(segments, z)], 1).tolist())
    verts.append([0.0, 0.0, profile[-1, 1]])
    top = len(verts) - 1
    j = np.arange(segments)
    k = (j + 1) % segments
    faces = [np.stack([np.zeros(segments, int), rings[0][k], rings[0][j]], 1)]
    for a, b in zip(rings[:-1], rings[1:]):
        faces.append(np.stack([a[j], a[k], b[k]], 1))
        faces.append(np.stack([a[j], b[k], b[j]], 1))
    faces.append(np.stack([np.full(segments, top), rings[-1][j], rings[-1][k]], 1))
    return np.asarray(verts), np.concatenate(faces).astype(np.int64)


def tube(path: np.ndarray, radius: float, sides: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube (capped) of circular section swept along a polyline `path` (P, 3), for mug handles."""
    path = np.asarray(path, dtype=np.float64)
    tang = np.gradient(path, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    # The handle path lies in the xz-plane, so y is a fixed normal and the frame never twists.
    side = np.array([0.0, 1.0, 0.0])
    normal = np.cross(side, tang)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = (np.cos(ang)[None, :, None] * normal[:, None, :] + np.sin(ang)[None, :, None] * side[None, None, :])
    verts = (path[:, None, :] + radius * ring).reshape(-1, 3)
    n = len(path)
    idx = np.arange(n * sides).reshape(n, sides)
    j = np.arange(sides)
    k = (j + 1) % sides
    faces = []
    for a, b in zip(idx[:-1], idx[1:]):
        faces.append(np.stack([a[j], b[k], b[j]], 1))
        faces.append(np.stack([a[j], a[k], b[k]], 1))
    # Caps: fans around the end centres.
    c0, c1 = len(verts), len(verts) + 1
    verts = np.vstack([verts, path[0], path[-1]])
    faces.append(np.stack([np.full(sides, c0), idx[0][k], idx[0][j]], 1))
    faces.append(np.stack([np.full(sides, c1), idx[-1][j], idx[-1][k]], 1))
    return verts, np.concatenate(faces).astype(np.int64)


def merge(*meshes: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, off = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    return np.vstack(verts), np.vstack(faces)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    return t * t * (3 - 2 * t)


# --------------------------------------------------------------------------------------------------- categories
def _box(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    # A unit cube scaled non-uniformly: log-uniform sides give flat slabs, cubes and tall blocks alike.
    dims = np.exp(rng.uniform(np.log(0.05), np.log(0.35), 3))
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)]) * dims
    v, f = convex_hull(corners)
    return v, f, {"dims": dims.round(5).tolist()}


def _cylinder(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    radius = rng.uniform(0.025, 0.13)
    height = np.exp(rng.uniform(np.log(0.04), np.log(0.38)))
    v, f = lathe(np.array([[0, 0], [radius, 0], [radius, height], [0, height]]), 40)
    return v, f, {"radius": round(radius, 5), "height": round(height, 5)}


def _bottle(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    # Solid lathe: foot chamfer, body (optionally waisted), curved shoulder, neck, lip.
    R = rng.uniform(0.025, 0.065)
    body_h = rng.uniform(0.08, 0.24)
    shoulder_h = rng.uniform(0.15, 0.6) * R + 0.01
    neck_r = max(0.008, rng.uniform(0.22, 0.5) * R)
    neck_h = rng.uniform(0.015, 0.08)
    lip = rng.uniform(0.0, 0.25) * neck_r
    waist = rng.uniform(0.0, 0.12) if rng.random() < 0.4 else 0.0
    foot = rng.uniform(0.04, 0.15) * R
    body_z = np.linspace(foot, body_h, 8)
    t = (body_z - foot) / max(body_h - foot, 1e-9)
    body_r = R * (1 - waist * np.sin(np.pi * t))
    s = np.linspace(0, 1, 9)[1:]
    sh_r = neck_r + (R - neck_r) * np.cos(0.5 * np.pi * _smoothstep(s))
    sh_z = body_h + shoulder_h * s
    top = body_h + shoulder_h + neck_h
    prof = [[0, 0], [R - foot, 0]] + list(zip(body_r, body_z)) + list(zip(sh_r, sh_z))
    prof += [[neck_r, top - 0.006], [neck_r + lip, top - 0.004], [neck_r + lip, top], [0, top]]
    v, f = lathe(np.array(prof), 36)
    return v, f, {"radius": round(R, 5), "body_h": round(body_h, 5), "shoulder_h": round(shoulder_h, 5),
                  "neck_r": round(neck_r, 5), "neck_h": round(neck_h, 5), "waist": round(waist, 4)}


def _mug(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    # Open-top hollow cup (bottom plate + wall, slightly flared) with a C handle swept in the xz-plane.
    R = rng.uniform(0.03, 0.06)
    H = rng.uniform(0.065, 0.14)
    flare = rng.uniform(1.0, 1.18)
    t = rng.uniform(0.003, 0.008)
    tb = rng.uniform(0.005, 0.012)
    Rt = R * flare
    prof = np.array([[0, 0], [R, 0], [Rt, H], [Rt - t, H], [R - t + (Rt - R) * tb / H, tb], [0, tb]])
    body = lathe(prof, 40)
    span = rng.uniform(0.45, 0.75) * H
    zc = rng.uniform(0.45, 0.6) * H
    reach = rng.uniform(0.018, 0.04)
    tr = rng.uniform(0.0035, 0.0075)
    squareness = rng.uniform(0.0, 0.6)
    th = np.linspace(-np.pi / 2, np.pi / 2, 17)
    # Superellipse-ish C: x bulges out by `reach`; ends sit inside the wall so the solids overlap slightly.
    cx = np.sign(np.cos(th)) * np.abs(np.cos(th)) ** (1 - squareness)
    z = zc + 0.5 * span * np.sign(np.sin(th)) * np.abs(np.sin(th)) ** (1 - squareness)
    wall_r = R + (Rt - R) * z / H
    x = wall_r - 0.5 * t + (reach + 0.5 * t) * cx
    handle = tube(np.stack([x, np.zeros_like(x), z], 1), tr, 10)
    v, f = merge(body, handle)
    return v, f, {"radius": round(R, 5), "height": round(H, 5), "flare": round(flare, 4), "wall": round(t, 5),
                  "handle_span": round(span, 5), "handle_reach": round(reach, 5)}


def _trashcan(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    # Open-top bin with a thin wall: round or polygonal section, tapered (wider at the top), optional rim.
    sides = int(rng.choice([4, 5, 6, 8, 48], p=[0.3, 0.1, 0.15, 0.15, 0.3]))
    Rb = rng.uniform(0.06, 0.15)
    H = rng.uniform(0.15, 0.38)
    Rt = Rb * rng.uniform(1.0, 1.35)
    t = rng.uniform(0.004, 0.01)
    tb = rng.uniform(0.006, 0.015)
    rim = rng.uniform(0.005, 0.015) if rng.random() < 0.5 else 0.0
    rim_h = 0.012
    inner_bottom = Rb - t + (Rt - Rb) * tb / H
    if rim > 0:
        prof = [[0, 0], [Rb, 0], [Rt, H - rim_h], [Rt + rim, H - rim_h], [Rt + rim, H], [Rt - t, H]]
    else:
        prof = [[0, 0], [Rb, 0], [Rt, H], [Rt - t, H]]
    prof += [[inner_bottom, tb], [0, tb]]
    phase = np.pi / sides if sides <= 8 else 0.0  # polygon edges (not corners) face +x
    v, f = lathe(np.array(prof), sides, phase)
    return v, f, {"sides": sides, "bottom_r": round(Rb, 5), "top_r": round(Rt, 5), "height": round(H, 5),
                  "wall": round(t, 5), "rim": round(rim, 5)}


def _speaker(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    # Box-like cabinet: bookshelf, tower or soundbar proportions; corners beveled (coarse) or rounded (fine);
    # optional taper towards the top or the back. Convex: the hull of corner-sphere samples.
    kind = rng.choice(["bookshelf", "tower", "bar", "cube"])
    if kind == "tower":
        w, d, h = rng.uniform(0.08, 0.18), rng.uniform(0.1, 0.22), rng.uniform(0.25, 0.4)
    elif kind == "bar":
        w, d, h = rng.uniform(0.25, 0.4), rng.uniform(0.06, 0.12), rng.uniform(0.05, 0.1)
    elif kind == "cube":
        w = rng.uniform(0.1, 0.25)
        d, h = w * rng.uniform(0.85, 1.15), w * rng.uniform(0.85, 1.15)
    else:
        w, d, h = rng.uniform(0.1, 0.2), rng.uniform(0.12, 0.22), rng.uniform(0.15, 0.3)
    radius = rng.uniform(0.0, 0.25) * min(w, d, h)
    levels = int(rng.choice([1, 2, 6]))  # 1: single bevel, 2: double bevel, 6: rounded
    taper_top = rng.uniform(0.0, 0.25) if rng.random() < 0.35 else 0.0
    taper_back = rng.uniform(0.0, 0.3) if rng.random() < 0.25 else 0.0
    # Octant samples of a sphere, `levels` latitude steps (ring i has i + 1 azimuths): with one level the
    # hull of the corner samples is a chamfer, with many a rounded edge.
    dir_list = []
    for i in range(levels + 1):
        phi = 0.5 * np.pi * i / levels
        for az in np.linspace(0.0, 0.5 * np.pi, i + 1) if i else [0.0]:
            dir_list.append([np.sin(phi) * np.cos(az), np.sin(phi) * np.sin(az), np.cos(phi)])
    dirs = np.asarray(dir_list)
    half = np.array([w, d, h]) / 2 - radius
    corners = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                sgn = np.array([sx, sy, sz])
                corners.append(sgn * half + radius * dirs * sgn)
    pts = np.vstack(corners)
    if radius == 0:
        pts = np.unique(pts, axis=0)
    zf = (pts[:, 2] + h / 2) / h  # 0 at the bottom, 1 at the top
    yf = (pts[:, 1] + d / 2) / d  # 0 at the front, 1 at the back
    pts[:, 0] *= 1 - taper_top * zf - 0.5 * taper_back * yf
    pts[:, 2] *= 1 - 0.5 * taper_back * yf * (pts[:, 2] > 0)
    v, f = convex_hull(pts)
    return v, f, {"kind": str(kind), "dims": [round(w, 5), round(d, 5), round(h, 5)],
                  "bevel_radius": round(radius, 5), "bevel_levels": levels, "taper_top": round(taper_top, 4),
                  "taper_back": round(taper_back, 4)}


_BUILDERS = {"box": (_box, True), "cylinder": (_cylinder, True), "bottle": (_bottle, True),
             "mug": (_mug, False), "trashcan": (_trashcan, False), "speaker": (_speaker, True)}
# Bottles are not strictly convex (the neck), but only the convex hull of a lone object can touch the plane,
# so the hull is an exact plane-contact geometry for them; mugs and trashcans get a convex decomposition.


def shape_seed(category: str, index: int, seed: int) -> int:
    """Seed of procedural shape `index` of `category`: independent of which other categories a dataset holds."""
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(1, zlib.crc32(category.encode()), int(index)))
    return int(ss.generate_state(1, np.uint64)[0])


def make_paper_shape(category: str, index: int, seed: int = 0) -> Shape:
    """Shape number `index` of the paper's category `category` for master `seed` (a pure function of its
    arguments)."""
    if category not in _BUILDERS:
        raise ValueError(f"unknown paper category {category!r}; known: {', '.join(CATEGORIES)}")
    if index < 0:
        raise ValueError(f"shape index must be >= 0, got {index}")
    s = shape_seed(category, index, seed)
    builder, convex = _BUILDERS[category]
    v, f, params = builder(np.random.default_rng(s))
    v = np.asarray(v, dtype=np.float64)
    v[:, 2] -= v[:, 2].min()
    return make_shape(f"{category}_{index:04d}", category, v, f, convex, seed=s % (2**31), params=params)
