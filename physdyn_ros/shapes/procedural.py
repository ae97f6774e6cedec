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
"""Every procedural category by name: the paper's six (`paper.py`) and the broader world's families
(`families.py`); `shapes.FAMILY_CATALOGUE` lists them all.

This module sits above both: the families reuse the paper's mesh builders and seeds, so the dispatch by name
cannot live in either without an import circle.
"""
from __future__ import annotations

from .core import Shape
from .families import ALL_CATEGORIES, FAMILIES, make_family_shape
from .paper import CATEGORIES, make_paper_shape

__all__ = ["CATEGORIES", "generate_shapes", "make_procedural"]


def make_procedural(category: str, index: int, seed: int = 0) -> Shape:
    """Procedural shape number `index` of `category` for master `seed` (a pure function of its arguments).
    `category` is one of the paper's six or one of the new families of `families.py`."""
    if category in CATEGORIES:
        return make_paper_shape(category, index, seed)
    if category in FAMILIES:
        return make_family_shape(category, index, seed)
    raise ValueError(f"unknown shape category {category!r}; known: {', '.join(ALL_CATEGORIES)}")


def generate_shapes(category: str, count: int, seed: int = 0) -> list[Shape]:
    """`count` distinct procedural shapes of `category` (indices 0..count-1)."""
    if count <= 0:
        raise ValueError(f"shape count must be positive, got {count}")
    return [make_procedural(category, i, seed) for i in range(count)]
