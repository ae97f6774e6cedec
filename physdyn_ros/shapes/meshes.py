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
"""User meshes (OBJ / STL / PLY) as Shapes, and the pybullet_data out-of-category test meshes.

The pybullet_data meshes (duck, teddy, bunny, lego, random_urdfs objects, ...) are NEVER used for training: the
generator puts the whole "pybullet_data" category in the test split. They are normalised to tabletop size.
"""
from __future__ import annotations

import os
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .core import Shape, convex_hull, make_shape, mesh_moments

PYBULLET_DATA_CATEGORY = "pybullet_data"
MESH_SUFFIXES = (".obj", ".stl", ".ply")
#: A loaded mesh whose volume is at least this fraction of its hull volume is treated as convex.
CONVEX_SOLIDITY = 0.97

_UP = {  # rotation taking the named source axis to +z (right-handed)
    "z": np.eye(3), "-z": np.diag([1.0, -1.0, -1.0]),
    "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), "-y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "x": np.array([[0, 0, -1.0], [0, 1, 0], [1, 0, 0]]), "-x": np.array([[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]]),
}


def _read(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a mesh file; open3d first, trimesh (no processing) as a fallback."""
    v = f = None
    try:
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # uv / material chatter
        m = o3d.io.read_triangle_mesh(str(path))
        if len(m.triangles):
            m.remove_duplicated_vertices()
            m.remove_degenerate_triangles()
            v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.triangles, dtype=np.int64)
    except Exception:  # noqa: BLE001 - any reader failure falls through to trimesh
        v = None
    if v is None or f is None or not len(f):
        try:
            import trimesh

            tm: Any = trimesh.load(str(path), force="mesh", process=False)  # a Trimesh (force="mesh")
            v, f = np.asarray(tm.vertices, dtype=np.float64), np.asarray(tm.faces, dtype=np.int64)
        except Exception as exc:  # noqa: BLE001
            raise ValueError(f"cannot read mesh {path}: {exc}") from None
    if v is None or f is None or len(f) == 0 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"cannot read mesh {path}: no triangles found")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"mesh {path} has non-finite vertex coordinates")
    return v, f


def load_mesh(path: str | os.PathLike, name: str | None = None, category: str = "custom", up_axis: str = "z",
              scale: float = 1.0, target_size: float | None = None, seed: int | None = None) -> Shape:
    """Load an OBJ / STL / PLY file as a Shape (units: metres after `scale`; `up_axis` of the file becomes +z).

    `target_size` (m), when given, rescales the mesh uniformly so its largest extent equals it. Raises ValueError
    when the file cannot be read or when the mesh is not closed enough to enclose a positive volume.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"unsupported mesh format {path.suffix!r} ({path}); use one of {', '.join(MESH_SUFFIXES)}")
    if up_axis not in _UP:
        raise ValueError(f"up_axis must be one of {sorted(_UP)}, got {up_axis!r}")
    if not scale > 0 or (target_size is not None and not target_size > 0):
        raise ValueError("scale and target_size must be positive")
    v, f = _read(path)
    v = v @ _UP[up_axis].T * scale
    if target_size is not None:
        v *= target_size / float((v.max(0) - v.min(0)).max())
    volume, _, _ = mesh_moments(v, f)
    if volume < 0:  # consistently inward-wound
        f, volume = f[:, ::-1].copy(), -volume
    extent = float((v.max(0) - v.min(0)).max())
    if not volume > 1e-9 * extent**3 or extent <= 0:
        raise ValueError(f"mesh {path} is not watertight enough: it encloses no positive volume "
                         f"({volume:.3g} m^3); close its holes or fix its face orientation")
    hv, hf = convex_hull(v)
    hull_volume, _, _ = mesh_moments(hv, hf)
    if volume > 1.05 * hull_volume:  # overlapping or duplicated parts: the divergence integral double counts
        raise ValueError(f"mesh {path} has self-overlapping parts (volume {volume:.3g} > hull {hull_volume:.3g}); "
                         "merge them into one closed surface")
    v[:, 2] -= v[:, 2].min()
    name = name or path.stem
    s = zlib.crc32(str(path.name).encode()) if seed is None else seed
    return make_shape(name, category, v, f, convex=volume >= CONVEX_SOLIDITY * hull_volume, seed=s,
                      params={"source": str(path), "up_axis": up_axis, "scale": scale, "target_size": target_size})


@dataclass(frozen=True)
class MeshSpec:
    """A pybullet_data mesh used as an out-of-category test object."""

    name: str
    path: Path
    up_axis: str
    size: float  # largest extent after normalisation, m


def _pybullet_data_dir() -> Path:
    import pybullet_data  # data-only package shipped with pybullet (it does not import pybullet)

    return Path(pybullet_data.getDataPath())


def pybullet_data_meshes(max_random: int = 60) -> list[MeshSpec]:
    """The out-of-category test meshes available in pybullet_data (sorted, deterministic).

    Named objects (duck, bunny, teddy, lego, torus, toy prism; the soccer ball is left out: its panels are open)
    plus up to `max_random` random_urdfs objects. Meshes that do not enclose a positive volume are skipped by
    `pybullet_data_shapes`.
    """
    root = _pybullet_data_dir()
    named = [("duck", "duck.obj", "y", 0.15), ("bunny", "bunny.obj", "y", 0.15),
             ("teddy", "teddy2_VHACD_CHs.obj", "y", 0.2), ("lego", "lego/lego.obj", "y", 0.08),
             ("torus", "torus/torus_textured.obj", "z", 0.15),
             ("prism", "toys/prism.obj", "z", 0.1)]
    specs = [MeshSpec(n, root / p, up, size) for n, p, up, size in named if (root / p).is_file()]
    rnd = sorted((root / "random_urdfs").glob("*/*.obj"))[:max(0, max_random)]
    rng = np.random.default_rng(7)
    sizes = rng.uniform(0.06, 0.25, len(rnd))
    specs += [MeshSpec(f"random_{p.stem}", p, "z", float(s)) for p, s in zip(rnd, sizes)]
    return specs


def pybullet_data_shapes(count: int | None = None, max_random: int = 60) -> list[Shape]:
    """Load the pybullet_data test meshes as Shapes of category "pybullet_data" (first `count` usable ones)."""
    shapes: list[Shape] = []
    for spec in pybullet_data_meshes(max_random):
        if count is not None and len(shapes) >= count:
            break
        try:
            shapes.append(load_mesh(spec.path, name=f"{PYBULLET_DATA_CATEGORY}_{spec.name}",
                                    category=PYBULLET_DATA_CATEGORY, up_axis=spec.up_axis, target_size=spec.size))
        except ValueError:
            continue  # open or self-overlapping mesh: not usable as a solid
    return shapes
