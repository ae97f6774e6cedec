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
"""The parameters of `physdyn generate`: DEFAULTS <- a YAML config (a path or a name in config/) <- the command
line, validated before anything is simulated (ValueError naming the bad value). The resolved dict is the
manifest's `generator` entry: a dataset is resumed only with exactly the same parameters.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import fields
from pathlib import Path
from typing import Any


#: Parameters that shape the data (compared when resuming). workers / shard_range / progress are not included.
DEFAULTS: dict[str, Any] = {
    "categories": ["box", "cylinder", "bottle", "mug", "trashcan", "speaker"],
    "shapes_per_category": 130,
    "num_sims": 50_000,
    "seed": 0,
    "shard_size": 256,
    "num_frames": 76,
    "friction": 0.5,
    "vary_friction": False,
    "meshes": [],
    "test_fraction": 0.2,
    "val_fraction": 0.1,
    "leave_out": [],
    "pybullet_data_max_random": 60,
    "sim": {},  # overrides of SimConfig fields
    "push": {},  # overrides of PushConfig fields
}
CONFIG_DIR = Path(__file__).resolve().parents[3] / "config"  # the repository's config/


def _load_yaml(spec: str) -> dict:
    import yaml

    path = Path(spec)
    if not path.is_file():
        named = CONFIG_DIR / (spec if spec.endswith((".yaml", ".yml")) else f"{spec}.yaml")
        if not named.is_file():
            raise ValueError(f"config file not found: {spec}")
        path = named
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"cannot parse config {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"config {path} must be a mapping of options")
    data = {k.replace("-", "_"): v for k, v in data.items()}
    unknown = sorted(set(data) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"config {path}: unknown options {unknown}; known: {sorted(DEFAULTS)}")
    return data


def _csv(value: str | list | None) -> list[str] | None:
    if value is None:
        return None
    items = value if isinstance(value, list) else str(value).split(",")
    return [str(x).strip() for x in items if str(x).strip()]


def _expand_meshes(items: list[str]) -> list[str]:
    from ...shapes.meshes import MESH_SUFFIXES

    out = []
    for item in items:
        path = Path(item).expanduser().resolve()
        if path.is_dir():
            found = sorted(str(f) for f in path.iterdir() if f.suffix.lower() in MESH_SUFFIXES)
            if not found:
                raise ValueError(f"mesh folder {path} holds no {'/'.join(MESH_SUFFIXES)} files")
            out += found
        else:
            out.append(str(path))
    return out


def resolve_params(args: argparse.Namespace) -> dict[str, Any]:
    """Defaults <- YAML config <- command line, validated. Raises ValueError on bad input."""
    from ...shapes import ALL_CATEGORIES, PYBULLET_DATA_CATEGORY
    from ..push import PushConfig
    from ..simulator import SimConfig

    p = json.loads(json.dumps(DEFAULTS))
    if getattr(args, "config", None):
        p.update(_load_yaml(args.config))
    cli = {"categories": _csv(getattr(args, "categories", None)), "num_sims": getattr(args, "num_sims", None),
           "shapes_per_category": getattr(args, "shapes_per_category", None), "seed": getattr(args, "seed", None),
           "shard_size": getattr(args, "shard_size", None), "num_frames": getattr(args, "num_frames", None),
           "friction": getattr(args, "friction", None), "meshes": getattr(args, "meshes", None),
           "leave_out": _csv(getattr(args, "leave_out", None)),
           "test_fraction": getattr(args, "test_fraction", None)}
    p.update({k: v for k, v in cli.items() if v is not None})
    if getattr(args, "vary_friction", None):
        p["vary_friction"] = True
    if getattr(args, "friction", None) is not None:
        p["vary_friction"] = False
    if getattr(args, "collision", None):
        p["sim"] = dict(p["sim"], collision=args.collision)
    p["categories"] = _csv(p["categories"]) or []
    p["leave_out"] = _csv(p["leave_out"]) or []
    p["meshes"] = _expand_meshes(p["meshes"] or [])
    if p["meshes"] and "custom" not in p["categories"]:
        p["categories"].append("custom")

    known = set(ALL_CATEGORIES) | {PYBULLET_DATA_CATEGORY, "custom"}
    if not p["categories"]:
        raise ValueError("no categories given")
    bad = [c for c in p["categories"] if c not in known]
    if bad:
        raise ValueError(f"unknown categories {bad}; known: {', '.join(sorted(known))}")
    if len(set(p["categories"])) != len(p["categories"]):
        raise ValueError(f"duplicate categories in {p['categories']}")
    if "custom" in p["categories"] and not p["meshes"]:
        raise ValueError("category 'custom' needs --mesh")
    for key in ("num_sims", "shapes_per_category", "shard_size", "num_frames", "pybullet_data_max_random"):
        if not isinstance(p[key], int) or isinstance(p[key], bool) or p[key] <= 0:
            raise ValueError(f"{key.replace('_', '-')} must be a positive integer, got {p[key]!r}")
    if p["num_frames"] < 61:
        raise ValueError(f"num-frames must be >= 61 (4 s roll-outs), got {p['num_frames']}")
    if not isinstance(p["seed"], int) or p["seed"] < 0:
        raise ValueError(f"seed must be a non-negative integer, got {p['seed']!r}")
    if not 0 < float(p["friction"]) <= 2:
        raise ValueError(f"friction must be in (0, 2], got {p['friction']}")
    p["friction"] = float(p["friction"])
    if not 0 <= float(p["test_fraction"]) < 1 or not 0 <= float(p["val_fraction"]) < 1:
        raise ValueError("test-fraction and val-fraction must be in [0, 1)")
    bad = [c for c in p["leave_out"] if c not in p["categories"]]
    if bad:
        raise ValueError(f"leave-out categories {bad} are not among the generated categories")
    for key, cls in (("sim", SimConfig), ("push", PushConfig)):
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(p[key]) - names)
        if unknown:
            raise ValueError(f"unknown {key} options {unknown}; known: {sorted(names)}")
    p["sim"].pop("vhacd_cache_dir", None)  # a path on this machine, not a data parameter
    sim_cfg = SimConfig(**{**p["sim"], "friction": p["friction"]})  # validates
    push: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in p["push"].items()}
    push_cfg = PushConfig(**push)  # validates
    p["sim"] = {k: v for k, v in sim_cfg.to_dict().items() if k != "vhacd_cache_dir"}
    p["push"] = {k: list(v) if isinstance(v, tuple) else v for k, v in push_cfg.to_dict().items()}
    return p


def parse_range(spec: str | None, num_shards: int) -> range:
    if spec is None:
        return range(num_shards)
    try:
        a, b = (int(x) if x else None for x in spec.split(":"))
    except ValueError:
        raise ValueError(f"--shard-range must look like A:B (shard indices), got {spec!r}") from None
    a = 0 if a is None else a
    b = num_shards if b is None else min(b, num_shards)
    if a < 0 or a >= b:
        raise ValueError(f"--shard-range {spec!r} selects no shard (the dataset has {num_shards} shards)")
    return range(a, b)
