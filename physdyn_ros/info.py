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
"""``physdyn info``: what this installation holds (interfaces, shipped model, versions)."""
from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")


def quiet_import(name: str):
    """Import a module whose C side prints to stdout on import (pybullet: "pybullet build time: ..."), with
    file descriptor 1 pointed at /dev/null meanwhile, so `physdyn info --json` prints JSON only."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            return importlib.import_module(name)
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _beside(load: Callable[[Path], Any], path: Path, pushes: str) -> str:
    """How info names a file fitted beside the shipped model: what it is for and was fitted on, none, or why it
    cannot be read."""
    try:
        fitted = load(path)
    except FileNotFoundError:
        return "none"
    except ValueError as exc:
        return f"unreadable ({exc})"
    return f"{path.name}, for {fitted.model_id}, fitted on {fitted.pushes} {pushes} of {fitted.fitted_on}"


def run(args: argparse.Namespace) -> int:
    from physdyn_ros import __version__
    from physdyn_ros.resources import DEFAULT_MODEL, share_dir

    info: dict[str, object] = {"physdyn_ros": __version__, "share": str(share_dir())}
    for mod in ("rclpy", "torch", "pybullet", "open3d", "numpy"):
        try:
            m = quiet_import(mod)
            info[mod] = getattr(m, "__version__", "installed")
        except ImportError as exc:  # the learning core works without ROS and pybullet
            info[mod] = f"missing ({exc})"
    try:
        from physdyn_ros import msg, srv
        info["interfaces"] = sorted(n for n in dir(msg) + dir(srv)
                                    if n[:1].isupper() and not n.endswith(("_Event", "_Request", "_Response")))
    except ImportError as exc:
        info["interfaces"] = f"not built ({exc}); run setup.sh"
    info["default_model"] = str(DEFAULT_MODEL) if DEFAULT_MODEL.exists() else "not shipped"
    if DEFAULT_MODEL.exists():
        from physdyn_ros.learn.checkpoint import load_checkpoint
        from physdyn_ros.resources import ensemble_models

        try:
            info["default_model_id"] = load_checkpoint(DEFAULT_MODEL)["model_id"]
        except Exception as exc:  # noqa: BLE001 - info reports a broken model, it does not fail on it
            info["default_model_id"] = f"unreadable ({exc})"
        from physdyn_ros.spread import SpreadCalibration, spread_path
        from physdyn_ros.topple_fusion import FusionWeights, fusion_path

        # Predictor.load(topple_fusion=True) and the planner's physics check read the one, rollout(spread=True)
        # and the nodes' rest_spread the other
        info["topple_fusion"] = _beside(FusionWeights.load, fusion_path(DEFAULT_MODEL), "pushes")
        info["spread_calibration"] = _beside(SpreadCalibration.load, spread_path(DEFAULT_MODEL), "upright pushes")
        members = []  # the planner's robustness check runs on these too (plan_ensemble)
        for path in ensemble_models():
            try:
                members.append(str(load_checkpoint(path)["model_id"]))
            except Exception as exc:  # noqa: BLE001 - reported, as a broken default model is
                members.append(f"{path.name} unreadable ({exc})")
        info["ensemble"] = ", ".join(members) or "none shipped"
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for k, v in info.items():
            print(f"{k:>18}: {v}")
    return 0
