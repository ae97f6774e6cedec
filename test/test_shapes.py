"""Shapes: procedural categories, mass properties, user meshes, pybullet_data test meshes (no pybullet here)."""
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
