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
"""trimesh computes the mesh moments and mass properties (shapes/core.py) and reads PLY clouds
(predictor.load_cloud); the hand-written versions they replaced are frozen here and the results must agree."""
from __future__ import annotations

import numpy as np
import pytest

from physdyn_ros.predictor import load_cloud
from physdyn_ros.shapes import make_procedural
from physdyn_ros.shapes.core import mass_properties, mesh_moments, orient_outward


def old_mesh_moments(vertices, faces):
    """shapes/core.mesh_moments before the move to trimesh (signed tetrahedra)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    s = a + b + c
    first = (vol[:, None] * s).sum(0) / 4.0
    outer = (np.einsum("ni,nj->nij", a, a) + np.einsum("ni,nj->nij", b, b) + np.einsum("ni,nj->nij", c, c)
             + np.einsum("ni,nj->nij", s, s))
    second = np.einsum("n,nij->ij", vol, outer) / 20.0
    return float(vol.sum()), first, second


def old_mass_properties(vertices, faces, density, scale):
    """The volume, COM and inertia of shapes/core.mass_properties before the move to trimesh."""
    volume, first, second = old_mesh_moments(np.asarray(vertices, dtype=np.float64) * np.asarray(scale), faces)
    com = first / volume
    c_com = (second - volume * np.outer(com, com)) * density
    inertia = np.trace(c_com) * np.eye(3) - c_com
    return volume, com, 0.5 * (inertia + inertia.T)


def assert_rel(new, old, rtol=1e-9, what="", scale=None):
    """|new - old| <= rtol * scale, scale = the largest |old| unless given (for arrays that are ~0)."""
    new, old = np.asarray(new, dtype=np.float64), np.asarray(old, dtype=np.float64)
    assert new.shape == old.shape
    scale = max(np.abs(old).max(), 1e-300) if scale is None else scale
    assert np.abs(new - old).max() <= rtol * scale, (what, np.abs(new - old).max() / scale)


SHAPES = [("box", 0), ("cylinder", 1), ("bottle", 2), ("mug", 3), ("trashcan", 0), ("speaker", 1),
          ("rock", 0), ("letter", 1), ("legged", 0), ("gear", 2)]


@pytest.mark.parametrize("category,index", SHAPES)
def test_mass_properties_equal_the_hand_written_moments(category, index):
    shape = make_procedural(category, index, seed=5)
    v, f = shape.vertices, shape.faces
    vol, first, second = mesh_moments(v, f)
    o_vol, o_first, o_second = old_mesh_moments(v, f)
    assert vol == pytest.approx(o_vol, rel=1e-9)
    size = abs(o_vol) * np.abs(v).max()
    assert_rel(first, o_first, what="first moment", scale=size)  # ~0: a Shape's origin is its COM
    assert_rel(second, o_second, what="second moment")
    shifted = v + [0.3, -0.2, 0.1]  # first moments away from zero
    assert_rel(mesh_moments(shifted, f)[1], old_mesh_moments(shifted, f)[1], what="shifted first moment")
    for scale, density in (((1.0, 1.0, 1.0), 500.0), ((1.3, 0.7, 2.1), 1000.0)):
        mp = mass_properties(v + [0.05, 0.0, -0.02], f, density=density, scale=scale)
        o_vol, o_com, o_inertia = old_mass_properties(v + [0.05, 0.0, -0.02], f, density, scale)
        assert mp.volume == pytest.approx(o_vol, rel=1e-9) and mp.mass == pytest.approx(o_vol * density, rel=1e-9)
        assert_rel(mp.com, o_com, what="com", scale=np.abs(v).max())
        assert_rel(mp.inertia, o_inertia, what="inertia")
        assert np.allclose(mp.inertia, mp.inertia.T, rtol=0, atol=1e-15 * np.abs(mp.inertia).max())
        moments, axes = np.linalg.eigh(o_inertia)
        assert_rel(mp.principal_moments, moments, what="principal moments")
        assert np.linalg.det(mp.principal_axes) == pytest.approx(1.0)


def test_inward_and_flat_meshes():
    shape = make_procedural("box", 0)
    inward = shape.faces[:, ::-1]
    vol, first, second = mesh_moments(shape.vertices, inward)
    o_vol, o_first, o_second = old_mesh_moments(shape.vertices, inward)
    assert vol < 0 and vol == pytest.approx(o_vol, rel=1e-9)
    assert_rel(second, o_second)
    np.testing.assert_array_equal(orient_outward(shape.vertices, inward), shape.faces)
    with pytest.raises(ValueError, match="no positive volume"):
        mass_properties(shape.vertices, inward)
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    faces = np.array([[0, 1, 2], [1, 3, 2], [0, 2, 1], [1, 2, 3]])
    with np.errstate(all="raise"):  # a zero volume: no division warnings either
        assert mesh_moments(flat, faces)[0] == 0.0
        with pytest.raises(ValueError, match="no positive volume"):
            mass_properties(flat, faces)


def _binary_ply(path, cloud, fmt="binary_little_endian", order="<"):
    header = f"ply\nformat {fmt} 1.0\nelement vertex {len(cloud)}\nproperty uchar red\nproperty float x\n" \
             "property float y\nproperty float z\nproperty double nx\nend_header\n"
    rows = np.zeros(len(cloud), dtype=[("red", "u1"), ("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"),
                                       ("nx", order + "f8")])
    rows["x"], rows["y"], rows["z"] = cloud.T
    path.write_bytes(header.encode() + rows.tobytes())
    return path


def test_ply_clouds_read_by_trimesh(tmp_path):
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(200, 3)) * 0.03
    for fmt, order in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
        got = load_cloud(_binary_ply(tmp_path / f"{fmt}.ply", cloud, fmt, order))
        assert got.dtype == np.float64 and np.allclose(got, cloud, atol=1e-7)
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text(f"ply\nformat ascii 1.0\ncomment from a scanner\nelement vertex {len(cloud)}\n"
                         "property double x\nproperty double y\nproperty double z\nend_header\n"
                         + "\n".join(" ".join(f"{c:.17g}" for c in p) for p in cloud) + "\n")
    np.testing.assert_array_equal(load_cloud(ascii_ply), cloud)
    mesh = tmp_path / "mesh.ply"  # a mesh's vertices are its points (the old reader refused this file)
    mesh.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n0.1 0 0\n0 0.1 0\n3 0 1 2\n")
    np.testing.assert_allclose(load_cloud(mesh), [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], atol=1e-7)


@pytest.mark.parametrize("content,message", [
    (b"", "not a ply file"),
    (b"hello\n1 2 3\n", "not a ply file"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float a\nproperty float b\nend_header\n1 2\n3 4\n",
     "no vertex property 'x'"),
    (b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
     "holds no vertices"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
     b"1 2 3\n", "declares 3 vertices, the file holds 1"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
     b"1 2 3\n4 five 6\n", "cannot read a PLY point cloud"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 50\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n" + bytes(100), "unexpected length"),
])
def test_bad_ply_files_are_refused_clearly(tmp_path, content, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="(?i)" + message) as info:
        load_cloud(path)
    assert str(path) in str(info.value)


def test_bad_ply_through_the_cli(tmp_path, capsys):
    from physdyn_ros.cli import main

    (tmp_path / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    code = main(["predict", "--cloud", str(tmp_path / "bad.ply"), "--lin-vel", "0.4", "0", "0",
                 "--ang-vel", "0", "0", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "bad.ply" in err and "Traceback" not in err
