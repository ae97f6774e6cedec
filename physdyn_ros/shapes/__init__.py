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
