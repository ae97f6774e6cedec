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
"""One name for every shape source: a mesh file, a procedural category or family, or a pybullet_data test mesh."""
from __future__ import annotations

from .core import Shape
from .meshes import PYBULLET_DATA_CATEGORY, load_mesh, pybullet_data_meshes
from .families import ALL_CATEGORIES
from .procedural import make_procedural


def resolve_shape(category: str, shape_seed: int = 0, mesh_path: str = "") -> Shape:
    """The shape `mesh_path` if given, else shape number `shape_seed` of `category` (a procedural category or
    "pybullet_data"). Raises ValueError naming the problem (unknown category, unreadable mesh)."""
    if mesh_path:
        return load_mesh(mesh_path)
    if category == PYBULLET_DATA_CATEGORY:
        specs = pybullet_data_meshes()
        if not specs:
            raise ValueError("no pybullet_data meshes are installed")
        # Some meshes are not closed solids: take the next usable one, deterministically.
        errors = []
        for i in range(len(specs)):
            spec = specs[(int(shape_seed) + i) % len(specs)]
            try:
                return load_mesh(spec.path, name=f"{PYBULLET_DATA_CATEGORY}_{spec.name}",
                                 category=PYBULLET_DATA_CATEGORY, up_axis=spec.up_axis, target_size=spec.size)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError("no usable pybullet_data mesh: " + "; ".join(errors[:3]))
    if category not in ALL_CATEGORIES:
        raise ValueError(f"unknown category {category!r}; use one of {', '.join(ALL_CATEGORIES)}, "
                         f"{PYBULLET_DATA_CATEGORY}, or a mesh file")
    return make_procedural(category, int(shape_seed))
