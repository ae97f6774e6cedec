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
"""Object-level splits: test shapes never appear in train or val (numpy only).

Per category, shapes are shuffled with the split seed; `test_fraction` of them go to test, and of the rest
`val_fraction` (10 % as in the paper) go to val. Categories in `test_only` (the pybullet_data out-of-category
meshes) go entirely to test, and `leave_out` moves whole categories to test (leave-one-category-out).
"""
from __future__ import annotations

import zlib
from typing import Iterable, Sequence

import numpy as np

SPLITS = ("train", "val", "test")
TEST_ONLY_CATEGORIES: tuple[str, ...] = ("pybullet_data",)


def make_splits(shapes: Sequence[dict], seed: int = 0, test_fraction: float = 0.2, val_fraction: float = 0.1,
                leave_out: Iterable[str] = (), test_only: Iterable[str] = TEST_ONLY_CATEGORIES) -> dict[str, list[str]]:
    """{"train", "val", "test"} -> sorted shape ids. `shapes` are manifest entries ({"id", "category", ...})."""
    if not 0 <= test_fraction < 1 or not 0 <= val_fraction < 1:
        raise ValueError("test_fraction and val_fraction must be in [0, 1)")
    ids = [s["id"] for s in shapes]
    if len(set(ids)) != len(ids):
        raise ValueError("shape ids are not unique")
    leave_out, test_only = set(leave_out), set(test_only)
    categories = sorted({s["category"] for s in shapes})
    unknown = leave_out - set(categories)
    if unknown:
        raise ValueError(f"leave_out categories {sorted(unknown)} are not in the dataset ({categories})")
    out: dict[str, list[str]] = {k: [] for k in SPLITS}
    for cat in categories:
        members = sorted(s["id"] for s in shapes if s["category"] == cat)
        if cat in leave_out or cat in test_only:
            out["test"] += members
            continue
        # Seeded per category so adding a category never reshuffles the others.
        rng = np.random.default_rng([int(seed), zlib.crc32(cat.encode())])
        order = [members[i] for i in rng.permutation(len(members))]
        n_test = int(round(test_fraction * len(order))) if len(order) > 1 else 0
        if test_fraction > 0 and len(order) > 2:
            n_test = max(n_test, 1)
        rest = order[n_test:]
        n_val = int(round(val_fraction * len(rest))) if len(rest) > 1 else 0
        if val_fraction > 0 and len(rest) > 2:
            n_val = max(n_val, 1)
        out["test"] += order[:n_test]
        out["val"] += rest[:n_val]
        out["train"] += rest[n_val:]
    return {k: sorted(v) for k, v in out.items()}


def check_disjoint(splits: dict[str, list[str]]) -> None:
    """Raise ValueError if a shape is in two splits."""
    seen: dict[str, str] = {}
    for name, ids in splits.items():
        for i in ids:
            if i in seen:
                raise ValueError(f"shape {i} is in both {seen[i]} and {name}")
            seen[i] = name


def leave_one_category_out(shapes: Sequence[dict], category: str, seed: int = 0,
                           val_fraction: float = 0.1) -> dict[str, list[str]]:
    """All shapes of `category` in test; every other (trainable) shape in train/val."""
    return make_splits(shapes, seed=seed, test_fraction=0.0, val_fraction=val_fraction, leave_out=[category])
