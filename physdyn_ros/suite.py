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
"""The node suite's definition and its parameter files: the nodes in start order (SPECS), the shipped params file
(config/suite.yaml) and what each node declares in it, user overrides checked against it and written as a second
params file, and the launch file's state_source overlays (config/state_source_<source>.yaml). `physdyn up`
(launcher.py) starts the suite with them; launch/physdyn.launch.py uses the same files.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import yaml


@dataclass(frozen=True)
class NodeSpec:
    """One node of the suite. Adding a node = one entry in SPECS, a `/**/<name>` section in config/suite.yaml, a
    `lifecycle_node(...)` line in launch/physdyn.launch.py and the script scripts/<executable> (test_ros_launch.py
    checks that they agree)."""

    #: node name: its params-file section `/**/<name>`, `--nodes` / `--param NAME:...` of `physdyn up`
    name: str
    #: the module physdyn_ros.nodes.<executable>, the installed script lib/physdyn_ros/<executable> (ros2 run /
    #: launch) and the launch file's `executable`; a managed (lifecycle) node with the parameter autostart
    executable: str
    #: it loads a checkpoint: `physdyn up --model` sets its model_path
    model: bool = False
    #: parameters of the params file's shared section (/**) that it does not declare
    not_declared: tuple[str, ...] = ()


#: The suite in start order.
SPECS: tuple[NodeSpec, ...] = (
    NodeSpec("sim", "sim_node", not_declared=("model_path",)),
    NodeSpec("perception", "perception_node", model=True),
    NodeSpec("predictor", "predictor_node", model=True),
    NodeSpec("pusher", "pusher_node", not_declared=("model_path",)),
)
#: (node name, executable) in start order.
NODES: tuple[tuple[str, str], ...] = tuple((spec.name, spec.executable) for spec in SPECS)
CONFIG_NAME = "suite.yaml"
#: The lifecycle state a node reaches on its own: with autostart, and without (a lifecycle manager takes over).
GOAL_STATE = {True: "active", False: "unconfigured"}
#: The Fast DDS profile the nodes get unless the user names one (config/fastdds.xml).
DDS_PROFILE_NAME = "fastdds.xml"
#: Fast DDS 2.x reads the first, Fast DDS 3 the second: both are set, to the same file.
DDS_PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
#: Parameters of the shipped params file's shared section (/**) that a node does not declare.
NOT_DECLARED = {spec.name: set(spec.not_declared) for spec in SPECS}


def default_config() -> Path:
    from .resources import config_path

    return config_path(CONFIG_NAME)


def dds_profile_env(env: dict[str, str]) -> str | None:
    """Point Fast DDS at config/fastdds.xml in `env` unless it already names a profile (either variable, even
    empty); returns the profile the nodes will use (None: Fast DDS's defaults, or the file is not installed)."""
    for var in DDS_PROFILE_VARS:
        if var in env:
            return env[var] or None
    try:
        from .resources import config_path

        path = str(config_path(DDS_PROFILE_NAME))
    except FileNotFoundError:
        return None
    for var in DDS_PROFILE_VARS:
        env[var] = path
    return path


def section(node: str) -> str:
    """The params-file key of a node: `/**/<name>` matches it in any namespace (`physdyn up --namespace`,
    the launch file's namespace argument); `/<name>` would match only the root namespace."""
    return f"/**/{node}"


def known_parameters(node: str) -> dict[str, Any]:
    """Name -> default of every parameter `node` declares, from the shipped params file (which lists them all:
    test_ros_launch.py compares it with the running nodes), plus rclpy's own two."""
    config = yaml.safe_load(default_config().read_text())
    params = dict(config["/**"]["ros__parameters"])
    for name in NOT_DECLARED.get(node, ()):
        params.pop(name, None)
    params.update(config[section(node)]["ros__parameters"])
    params.setdefault("use_sim_time", False)  # rclpy's own, on every node
    params.setdefault("start_type_description_service", True)
    return params


def parse_overrides(node: str, assignments: Sequence[str]) -> dict[str, Any]:
    """["name:=value", ...] -> {name: value}; values are YAML as with -p, and an integer given for a
    floating-point parameter becomes a float (0 for real_time_factor 0.0). ValueError names a bad assignment
    or a parameter the node does not have."""
    known = known_parameters(node)
    out: dict[str, Any] = {}
    for item in assignments:
        name, sep, text = item.partition(":=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"parameter override {item!r} of node '{node}': use NAME:=VALUE")
        if name not in known:
            raise ValueError(f"node '{node}' has no parameter '{name}'; its parameters are: "
                             f"{', '.join(sorted(known))}")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError as exc:
            raise ValueError(f"parameter override {item!r} of node '{node}': value is not valid YAML ({exc})")
        try:
            out[name] = typed_like(known[name], value)
        except ValueError as exc:
            raise ValueError(f"parameter override {item!r} of node '{node}': {exc}") from None
    return out


def _type_name(value: Any) -> str:
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}.get(type(value), "a list")


def typed_like(default: Any, value: Any) -> Any:
    """`value` as the type of the parameter whose default is `default` (rcl keeps the params file's first value
    when a later file gives another type, so a wrong type must be refused here). An integer is a valid float
    (0 for real_time_factor 0.0) and a YAML number a valid string (object_id:=7); ValueError says what is
    expected."""
    def one(d: Any, v: Any) -> Any:
        if isinstance(d, bool):
            if isinstance(v, bool):
                return v
        elif isinstance(d, int):
            if isinstance(v, int) and not isinstance(v, bool):
                return v
        elif isinstance(d, float):
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                return float(v)
        elif isinstance(d, str):
            if isinstance(v, str):
                return v
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                return str(v)
        else:
            return v
        raise ValueError(f"expects {_type_name(d)}, got {v!r}")

    if isinstance(default, list):
        if not isinstance(value, list):
            raise ValueError(f"expects a list like {default!r}, got {value!r}")
        return [one(default[0], v) for v in value] if default else value
    if isinstance(value, list):
        raise ValueError(f"expects {_type_name(default)}, got the list {value!r}")
    return one(default, value)


def write_overrides(node: str, values: dict[str, Any], folder: Path) -> Path:
    """A params file with `values` in `node`'s own section (given after the main one, so it wins)."""
    path = folder / f"{node}_overrides.yaml"
    path.write_text(yaml.safe_dump({section(node): {"ros__parameters": values}}, default_flow_style=None))
    return path


def state_source_overlay(source: str) -> dict[str, list[str]]:
    """node -> NAME:=VALUE of config/state_source_<source>.yaml, the launch file's state_source overlay."""
    from .resources import config_path

    sections = yaml.safe_load(config_path(f"state_source_{source}.yaml").read_text())
    return {key.rsplit("/", 1)[-1]: [f"{k}:={v!r}" if isinstance(v, float) else f"{k}:={v}"
                                     for k, v in section["ros__parameters"].items()]
            for key, section in sections.items()}
