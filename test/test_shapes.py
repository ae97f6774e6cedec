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
"""Shapes: procedural categories and families, mass properties, user meshes, pybullet_data test meshes.

pybullet only in the settle / collision tests of the families (the shapes package itself never imports it)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from physdyn_ros.conventions import NUM_POINTS
from physdyn_ros.shapes import (CATEGORIES, PYBULLET_DATA_CATEGORY, Shape, generate_shapes, load_mesh,
                                make_procedural, mass_properties, pybullet_data_meshes, pybullet_data_shapes,
                                shape_from_points)
from physdyn_ros.shapes.core import mesh_moments

CONCAVE = {"mug", "trashcan"}


def _box_mesh(dims):
    from physdyn_ros.shapes import convex_hull

    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)]) * np.asarray(dims)
    return convex_hull(corners)


@pytest.mark.parametrize("category", CATEGORIES)
def test_category_is_a_varied_valid_family(category):
    shapes = generate_shapes(category, 12, seed=3)
    assert [s.name for s in shapes] == [f"{category}_{i:04d}" for i in range(12)]
    extents = np.array([s.extents for s in shapes])
    # Tabletop sizes, and real variety (not templates): every shape differs, sizes spread.
    assert extents.max() <= 0.45 and extents.max(1).min() >= 0.05, extents
    assert len({tuple(np.round(e, 4)) for e in extents}) == 12
    assert np.ptp(extents.max(1)) > 0.03
    for s in shapes:
        assert isinstance(s, Shape) and s.category == category
        assert s.vertices.dtype == np.float64 and s.vertices.shape[1] == 3 and s.faces.shape[1] == 3
        assert s.convex == (category not in CONCAVE)
        mp = s.mass_properties()
        assert mp.volume > 0 and mp.mass > 0
        np.testing.assert_allclose(mp.com, 0, atol=1e-9)  # object frame origin = centre of mass
        assert s.points.shape == (NUM_POINTS, 3) and s.points.dtype == np.float32
        lo, hi = s.bounds
        assert np.all(s.points >= lo - 1e-6) and np.all(s.points <= hi + 1e-6)
        # z is up: the shape stands on its lowest face, below the COM.
        assert lo[2] < 0 < hi[2]
        assert np.all(np.linalg.eigvalsh(mp.inertia) > 0)


def test_procedural_is_deterministic_and_seeded():
    a, b = make_procedural("bottle", 5, seed=1), make_procedural("bottle", 5, seed=1)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.points, b.points)
    c = make_procedural("bottle", 5, seed=2)
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)
    # A category's shapes do not depend on which other categories are generated with it.
    np.testing.assert_array_equal(generate_shapes("mug", 3, 1)[2].vertices, make_procedural("mug", 2, 1).vertices)
    with pytest.raises(ValueError, match="unknown shape category"):
        make_procedural("chair", 0)
    with pytest.raises(ValueError, match="positive"):
        generate_shapes("box", 0)


def test_mass_properties_match_analytic_box_under_scale():
    dims = np.array([0.1, 0.2, 0.3])
    v, f = _box_mesh(dims)
    scale = np.array([1.5, 0.5, 1.2])
    mp = mass_properties(v, f, density=1000.0, scale=scale)
    a, b, c = dims * scale
    m = 1000.0 * a * b * c
    assert mp.mass == pytest.approx(m, rel=1e-9)
    np.testing.assert_allclose(np.diag(mp.inertia), [m * (b * b + c * c) / 12, m * (a * a + c * c) / 12,
                                                     m * (a * a + b * b) / 12], rtol=1e-9)
    np.testing.assert_allclose(mp.inertia - np.diag(np.diag(mp.inertia)), 0, atol=1e-12)
    with pytest.raises(ValueError):
        mass_properties(v, f, scale=(1, 0, 1))
    with pytest.raises(ValueError, match="positive volume"):
        mass_properties(v, f[:, ::-1])  # inward faces


def test_cylinder_inertia_close_to_analytic():
    s = make_procedural("cylinder", 0)
    r, h = s.params["radius"], s.params["height"]
    mp = s.mass_properties(density=1.0)
    m = mp.mass
    # 40-gon: within 1 % of the round cylinder.
    assert mp.volume == pytest.approx(np.pi * r * r * h, rel=0.01)
    assert mp.inertia[2, 2] == pytest.approx(m * r * r / 2, rel=0.01)
    assert mp.inertia[0, 0] == pytest.approx(m * (3 * r * r + h * h) / 12, rel=0.01)


def test_mug_has_products_of_inertia_and_a_handle():
    s = make_procedural("mug", 1)
    mp = s.mass_properties()
    assert abs(mp.inertia[0, 2]) > 1e-4 * np.trace(mp.inertia)  # handle in +x, off the axis
    axes = mp.principal_axes
    np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    np.testing.assert_allclose(axes @ np.diag(mp.principal_moments) @ axes.T, mp.inertia, atol=1e-12)
    hull_volume = mass_properties(*s.hull()).volume
    assert mp.volume < 0.5 * hull_volume  # hollow: strongly concave


def test_load_mesh_formats_and_errors(tmp_path):
    import open3d as o3d

    v, f = _box_mesh([0.1, 0.05, 0.2])
    obj = tmp_path / "box.obj"
    obj.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in f))
    s = load_mesh(obj)
    assert s.name == "box" and s.category == "custom" and s.convex
    np.testing.assert_allclose(s.extents, [0.1, 0.05, 0.2], atol=1e-9)
    assert s.mass_properties().volume == pytest.approx(0.001, rel=1e-6)
    # y-up file, STL and PLY via open3d
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
    mesh.compute_triangle_normals()
    for suffix in (".stl", ".ply"):
        path = tmp_path / f"box{suffix}"
        o3d.io.write_triangle_mesh(str(path), mesh)
        t = load_mesh(path, up_axis="y", target_size=0.3)
        np.testing.assert_allclose(t.extents, [0.15, 0.3, 0.075], atol=1e-6)
    with pytest.raises(ValueError, match="not found"):
        load_mesh(tmp_path / "missing.obj")
    bad = tmp_path / "garbage.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="cannot read"):
        load_mesh(bad)
    flat = tmp_path / "flat.obj"  # an open square: no volume
    flat.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    with pytest.raises(ValueError, match="watertight"):
        load_mesh(flat)
    txt = tmp_path / "box.txt"
    txt.write_text("x")
    with pytest.raises(ValueError, match="unsupported"):
        load_mesh(txt)


def test_pybullet_data_test_meshes():
    specs = pybullet_data_meshes(max_random=5)
    names = [s.name for s in specs]
    assert "duck" in names and "bunny" in names and "teddy" in names
    assert sum(n.startswith("random_") for n in names) == 5
    assert all(s.path.is_file() for s in specs)
    shapes = pybullet_data_shapes(count=4, max_random=5)
    assert len(shapes) == 4
    for s in shapes:
        assert s.category == PYBULLET_DATA_CATEGORY and s.name.startswith("pybullet_data_")
        assert 0.04 <= s.extents.max() <= 0.3
        assert s.mass_properties().volume > 0


def test_shape_from_points_keeps_frame():
    pts = np.random.default_rng(0).uniform(-0.05, 0.05, (500, 3))
    s = shape_from_points(pts)
    assert s.convex and s.points.shape == (500, 3)
    vol, _, _ = mesh_moments(s.vertices, s.faces)
    assert 0 < vol <= 0.1 ** 3
    with pytest.raises(ValueError):
        shape_from_points(np.zeros((10, 3)))


def test_shapes_and_data_do_not_import_pybullet():
    code = ("import sys, physdyn_ros.shapes, physdyn_ros.data; "
            "bad = [m for m in ('pybullet', 'torch', 'rclpy') if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------------------------------ the broad world
from physdyn_ros.shapes import (ALL_CATEGORIES, FAMILIES, FAMILY_CATALOGUE, HELD_OUT_FAMILIES,  # noqa: E402
                                resolve_shape)
from physdyn_ros.shapes import solids  # noqa: E402
from scipy.sparse.csgraph import connected_components  # noqa: E402


def _inside_depth(points: np.ndarray, part: np.ndarray) -> np.ndarray:
    """How deep each point lies inside the convex hull of `part` (m; <= 0: outside or on its surface)."""
    from physdyn_ros.shapes import convex_hull

    n, d = solids._planes(*convex_hull(part))
    return -(np.asarray(points, dtype=np.float64) @ n.T - d).max(1)


def _touching(a: np.ndarray, b: np.ndarray, tol: float = 1e-7) -> bool:
    """Whether the convex hulls of two pieces share a point (touch or overlap): a point inside both, by LP."""
    from scipy.optimize import linprog

    from physdyn_ros.shapes import convex_hull

    (na, da), (nb, db) = solids._planes(*convex_hull(a)), solids._planes(*convex_hull(b))
    res = linprog(np.zeros(3), A_ub=np.vstack([na, nb]), b_ub=np.concatenate([da, db]) + tol, bounds=[(None, None)] * 3)
    return bool(res.status == 0)


def test_family_catalogue():
    names = [f.name for f in FAMILY_CATALOGUE]
    assert tuple(names) == ALL_CATEGORIES == CATEGORIES + FAMILIES
    assert len(FAMILIES) >= 10 and not set(FAMILIES) & set(CATEGORIES)
    assert {f.group for f in FAMILY_CATALOGUE if f.name in CATEGORIES} == {"paper"}
    assert len({f.group for f in FAMILY_CATALOGUE}) >= 6 and all(f.description for f in FAMILY_CATALOGUE)
    assert len(HELD_OUT_FAMILIES) >= 3 and set(HELD_OUT_FAMILIES) <= set(FAMILIES)
    for fam in FAMILIES:  # every way of naming a shape accepts the families
        a, b = resolve_shape(fam, 4, ""), make_procedural(fam, 4)
        assert a.name == b.name == f"{fam}_0004" and a.category == fam
        np.testing.assert_array_equal(a.vertices, b.vertices)
    with pytest.raises(ValueError, match="unknown category"):
        resolve_shape("chair", 0, "")


@pytest.mark.parametrize("family", FAMILIES)
def test_family_is_a_varied_closed_solid(family):
    entry = {f.name: f for f in FAMILY_CATALOGUE}[family]
    shapes = generate_shapes(family, 10, seed=3)
    assert [s.name for s in shapes] == [f"{family}_{i:04d}" for i in range(10)]
    extents = np.array([s.extents for s in shapes])
    # Tabletop sizes (largest extent 4-40 cm, nothing thinner than 1.2 cm) and real variety.
    assert extents.max(1).min() >= 0.04 and extents.max() <= 0.40 + 1e-12, extents  # _fit: rounding
    assert extents.min() >= 0.012, extents
    assert len({tuple(np.round(e, 5)) for e in extents}) == 10
    assert len({s.fingerprint() for s in shapes}) == 10
    assert np.ptp(extents.max(1)) > 0.03
    for s in shapes:
        assert s.category == family and s.convex == entry.convex
        # Closed and outward: positive signed volume, the same wherever the origin is, face areas cancel.
        vol, _, _ = mesh_moments(s.vertices, s.faces)
        assert vol > 0
        assert mesh_moments(s.vertices + [0.3, -0.2, 0.5], s.faces)[0] == pytest.approx(vol, rel=1e-9)
        assert solids.closure_error(s.vertices, s.faces) < 1e-9
        mp = s.mass_properties()
        assert np.all(np.isfinite(mp.inertia)) and mp.mass > 0
        np.testing.assert_allclose(mp.com, 0, atol=1e-9)  # object frame origin = centre of mass
        moments = np.linalg.eigvalsh(mp.inertia)
        assert moments.min() > 0 and moments.max() <= moments.sum() - moments.max() + 1e-15  # triangle inequality
        assert s.points.shape == (NUM_POINTS, 3) and np.all(np.isfinite(s.points))
        lo, hi = s.bounds
        assert np.all(s.points >= lo - 1e-6) and np.all(s.points <= hi + 1e-6)
        # Upright on a face: the centre of mass is above the plane and over the support polygon.
        assert lo[2] < 0 < hi[2]
        assert solids.support_margin(s.vertices, np.zeros(3)) > 0
        hull_volume = mass_properties(*s.hull()).volume
        if entry.convex:
            assert s.parts is None and vol == pytest.approx(hull_volume, rel=1e-6)
            continue
        # Convex pieces: inside the bounds, together at least the solid (overlaps count once in the solid).
        assert s.parts and all(p.shape[1] == 3 and len(p) >= 4 for p in s.parts)
        assert np.all(np.vstack(s.parts) >= lo - 1e-9) and np.all(np.vstack(s.parts) <= hi + 1e-9)
        part_volumes = sum(mass_properties(*solids.convex_hull(p)).volume for p in s.parts)
        assert vol <= part_volumes * (1 + 1e-9) and vol < hull_volume * (1 + 1e-9)
        # The cloud lies on the union's surface, never inside a piece (the faces where pieces meet are gone).
        assert max(_inside_depth(s.points, p).max() for p in s.parts) < 1e-6
        # One body: the pieces, linked where two touch or overlap, form one connected graph.
        touch = np.array([[i != j and _touching(a, b) for j, b in enumerate(s.parts)] for i, a in enumerate(s.parts)])
        assert connected_components(touch, directed=False)[0] == 1, s.name


@pytest.mark.parametrize("family", FAMILIES)
def test_family_is_deterministic_per_seed(family):
    a, b = make_procedural(family, 2, seed=1), make_procedural(family, 2, seed=1)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.points, b.points)
    assert a.params == b.params and (a.parts is None) == (b.parts is None)
    for p, q in zip(a.parts or (), b.parts or ()):
        np.testing.assert_array_equal(p, q)
    np.testing.assert_array_equal(generate_shapes(family, 3, 1)[2].vertices, a.vertices)
    assert make_procedural(family, 2, seed=2).fingerprint() != a.fingerprint()
    assert make_procedural(family, 3, seed=1).fingerprint() != a.fingerprint()


def test_paper_categories_unchanged():
    """The six paper categories draw fixed shapes for fixed seeds (digests of their parameters, names, convex
    flags, volumes, no parts): datasets generated from them stay reproducible."""
    import hashlib
    import json

    expected = {"box": "30b5b54a2bac3a86", "cylinder": "8243752bd65f1aff", "bottle": "2e7d1fb6cb797fe8",
                "mug": "f20dac1f7c26c575", "trashcan": "558ea71a23d22245", "speaker": "272d0e2e399bd40d"}
    for c in CATEGORIES:
        data = json.dumps([[s.name, s.convex, s.params, round(float(s.mass_properties().volume), 9), s.parts]
                           for s in generate_shapes(c, 4, seed=0)], sort_keys=True)
        assert hashlib.sha256(data.encode()).hexdigest()[:16] == expected[c], c


def test_union_surface_mass_properties_are_exact():
    box = solids.box_points
    # Overlapping boxes: the overlap counts once.
    v, f = solids.union_surface([box((0, 0, 0), (2, 1, 1)), box((1, 0, 0), (3, 1, 1))])
    mp = mass_properties(v, f, density=1.0)
    assert mp.volume == pytest.approx(3.0, rel=1e-12)
    np.testing.assert_allclose(mp.com, [1.5, 0.5, 0.5], atol=1e-12)
    np.testing.assert_allclose(np.diag(mp.inertia), [(1 + 1) / 12 * 3, (9 + 1) / 12 * 3, (9 + 1) / 12 * 3],
                               rtol=1e-12)
    # A box standing face to face on a bigger one: the touching faces vanish, the area is the union's.
    v, f = solids.union_surface([box((0, 0, 0), (2, 2, 1)), box((0.5, 0.5, 1), (1.5, 1.5, 2))])
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert mass_properties(v, f, density=1.0).volume == pytest.approx(5.0, rel=1e-12)
    assert area == pytest.approx(4 + 3 + 8 + 1 + 4, rel=1e-12) and solids.closure_error(v, f) < 1e-12
    # A ball sunk into a box: the union's volume (Monte Carlo, 0.3 % here) and a closed surface.
    ball = solids.ellipsoid_points((0.5, 0.5, 0.5), 12, 24) + [1.0, 1.0, 1.2]
    v, f = solids.union_surface([box((0, 0, 0), (2, 2, 1)), ball])
    q = np.random.default_rng(0).uniform([0, 0, 0], [2, 2, 1.7], (400_000, 3))
    inside = (q[:, 2] <= 1) | (_inside_depth(q, ball) > 0)
    assert mass_properties(v, f).volume == pytest.approx(inside.mean() * 2 * 2 * 1.7, rel=0.003)
    assert solids.closure_error(v, f) < 1e-9


def test_rest_on_stable_face():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 3.0]]) @ np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0.0]])
    v, f = solids.convex_hull(pts)
    com = mass_properties(v, f).com
    assert solids.support_margin(v, com) < 0  # lying on its side face, it would tip
    rot, score = solids.rest_on_stable_face(v, f)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0) and score > 0
    assert solids.support_margin(v @ rot.T, com @ rot.T) > 0


def _settle(shape, scale=(1.0, 1.0, 1.0), collision="auto", cache=None):
    from physdyn_ros.sim import SimConfig, Simulator
    from physdyn_ros.sim.simulator import tilt_angle

    sim = Simulator(SimConfig(collision=collision, vhacd_cache_dir=str(cache) if cache else None))
    sim.spawn(shape, scale=scale, yaw=0.7)
    for _ in range(15):  # 1 s more, untouched
        pos, q, v, w = sim.step_frame()
    return sim, float(np.degrees(tilt_angle(q))), float(np.linalg.norm(v)), float(np.linalg.norm(w)), pos


@pytest.mark.parametrize("family", FAMILIES)
def test_family_settles_upright_in_pybullet(family, tmp_path):
    rng = np.random.default_rng(zlib_crc(family))
    shape = make_procedural(family, int(rng.integers(0, 1000)))
    sim, tilt, v, w, pos = _settle(shape, scale=rng.uniform(0.6, 1.4, 3), cache=tmp_path)
    try:
        assert tilt < 0.5 and v < 1e-3 and w < 0.02, (shape.name, tilt, v, w)
        # Resting on the plane (Bullet's ~1 mm margin), where it was spawned.
        lo, _ = sim.aabb()
        assert 0.0 < lo[2] < 0.003 and np.linalg.norm(pos[:2]) < 1e-3
        pieces = sim.client.getCollisionShapeData(sim.body, -1)
        assert len(pieces) == (1 if shape.convex else len(shape.parts))  # a compound of the shape's own pieces
    finally:
        sim.close()


def _area_2d(points: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    return float(ConvexHull(points[:, :2]).volume) if len(points) >= 3 else 0.0


def test_new_regimes_have_their_geometry():
    """The families that widen the world keep what they were made for, over several seeds: rockers rest on a
    small flat of a curved side; topheavy objects tip at a small angle (the centre of mass high over a narrow
    foot); every tool has a thin handle as long as its parameters say."""
    for seed in range(3):
        for s in generate_shapes("rocker", 10, seed=seed):
            base = s.vertices[s.vertices[:, 2] < s.vertices[:, 2].min() + 1e-6]
            assert _area_2d(base) < 0.45 * _area_2d(s.vertices), s.name
        tip = [solids.support_margin(s.vertices, np.zeros(3)) / -s.vertices[:, 2].min()  # origin: the centre of mass
               for s in generate_shapes("topheavy", 10, seed=seed)]
        assert max(tip) < 1.0 and np.median(tip) < 0.5, tip  # tipping angles under 45 degrees, most under 27
        for s in generate_shapes("tool", 10, seed=seed):
            k = s.params.get("fit_scale", 1.0)
            spans = [np.sort(np.ptp((p - p.mean(0)) @ np.linalg.svd(p - p.mean(0))[2].T, axis=0)) for p in s.parts]
            assert len(spans) == 2 and any(e[0] <= 2.02 * s.params["handle_radius"] * k
                                           and e[2] >= 0.95 * s.params["handle_length"] * k for e in spans), s.name


def zlib_crc(text: str) -> int:
    import zlib

    return zlib.crc32(text.encode())


def test_parts_collision_is_the_solid_not_its_hull(tmp_path):
    """A ring collides as its segments: a ray through the hole passes (through the hull it would not); with
    collision="parts" a shape without parts (a mug) uses its hull, no V-HACD."""
    ring = make_procedural("ring", 0)
    for collision, hits in (("auto", False), ("parts", False), ("hull", True)):
        sim, *_ = _settle(ring, collision=collision, cache=tmp_path / collision)
        try:
            pos, *_ = sim.state()
            top = sim.aabb()[1][2]
            hit = sim.ray_test(np.array([pos[0], pos[1], top + 0.1]), np.array([pos[0], pos[1], -0.01]))
            assert (hit is not None) == hits, collision
        finally:
            sim.close()
    sim, tilt, *_ = _settle(make_procedural("mug", 0), collision="parts", cache=tmp_path / "mug")
    sim.close()
    assert tilt < 0.5 and not list((tmp_path / "mug").glob("*.obj"))
