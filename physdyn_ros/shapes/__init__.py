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
"""Shapes: procedural categories and families, user meshes, mass properties.

numpy / open3d / trimesh only: never pybullet.
"""
from .core import DEFAULT_DENSITY, MassProperties, Shape, convex_hull, make_shape, mass_properties, sample_surface, \
    shape_from_points
from .meshes import PYBULLET_DATA_CATEGORY, load_mesh, pybullet_data_meshes, pybullet_data_shapes
from .families import ALL_CATEGORIES, FAMILIES, FAMILY_CATALOGUE, HELD_OUT_FAMILIES
from .paper import CATEGORIES, shape_seed
from .procedural import generate_shapes, make_procedural
from .resolve import resolve_shape

__all__ = ["ALL_CATEGORIES", "CATEGORIES", "DEFAULT_DENSITY", "FAMILIES", "FAMILY_CATALOGUE", "HELD_OUT_FAMILIES",
           "MassProperties", "PYBULLET_DATA_CATEGORY", "Shape", "convex_hull", "generate_shapes", "load_mesh",
           "make_procedural", "make_shape", "mass_properties", "pybullet_data_meshes", "pybullet_data_shapes",
           "resolve_shape", "sample_surface", "shape_from_points", "shape_seed"]
