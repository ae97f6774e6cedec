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

PACKAGE_DIR = Path(__file__).resolve().parent
DEFAULT_MODEL = PACKAGE_DIR / "models" / "default.pt"


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
