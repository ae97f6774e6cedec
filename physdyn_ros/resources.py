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
"""Where installed files live: config YAMLs, launch files, the shipped model.

The same code runs from the source tree (editable install, setup.sh), from a colcon install
(share/physdyn_ros via the ament index) and from a plain pip install (<prefix>/share/physdyn_ros).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Sequence

PACKAGE_DIR = Path(__file__).resolve().parent
DEFAULT_MODEL = PACKAGE_DIR / "models" / "default.pt"


def ensemble_models() -> list[Path]:
    """The shipped ensemble's further members (models/ensemble-*.pt; the default model is its first): the same
    network fine-tuned from it on other data and seeds, each with its own topple head (the model card)."""
    return sorted((PACKAGE_DIR / "models").glob("ensemble-*.pt"))


def ensemble_paths(size: int, model_path: str = "", members: Sequence[str] = ()) -> list[str]:
    """The checkpoints of the further members of a `size`-model ensemble whose first model is `model_path` (""
    the shipped one): `members` where given (empty entries ignored), else the shipped members, which belong to the
    shipped model only. Size 0: every member named, else with the shipped model every shipped one, else none.
    ValueError with the reason when there are too few."""
    given = [str(m) for m in members if str(m).strip()]
    if size < 0:
        raise ValueError(f"an ensemble of {size} models")
    if size == 0:
        return given if given or model_path else [str(p) for p in ensemble_models()]
    if size == 1:
        return []
    if not given and model_path:
        raise ValueError(f"an ensemble of {size}: the shipped members belong to the shipped model, not {model_path}; "
                         f"name {size - 1} further checkpoints")
    found = given or [str(p) for p in ensemble_models()]
    if len(found) < size - 1:
        raise ValueError(f"an ensemble of {size} needs {size - 1} further members, "
                         f"{'the names give' if given else 'the package ships'} {len(found)}")
    return found[:size - 1]


def share_dir() -> Path:
    """The folder holding config/ and launch/ for this installation."""
    candidates = [PACKAGE_DIR.parent]  # source tree: the repository root
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "physdyn_ros")
    candidates.append(Path(sys.prefix) / "share" / "physdyn_ros")
    for c in candidates:
        if (c / "config").is_dir():
            return c
    raise FileNotFoundError("physdyn_ros config/ folder not found (looked in: "
                            + ", ".join(str(c) for c in candidates) + ")")


def config_path(name: str) -> Path:
    """Path of config/<name>; a clear error if it does not exist."""
    path = share_dir() / "config" / name
    if not path.is_file():
        raise FileNotFoundError(f"no config file {name!r} in {path.parent}")
    return path
