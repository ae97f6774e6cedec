"""``physdyn info``: what this installation holds (interfaces, shipped model, versions)."""
from __future__ import annotations

import argparse
import importlib
import json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")


def run(args: argparse.Namespace) -> int:
    from physdyn_ros import __version__
    from physdyn_ros.resources import DEFAULT_MODEL, share_dir

    info: dict[str, object] = {"physdyn_ros": __version__, "share": str(share_dir())}
    for mod in ("rclpy", "torch", "pybullet", "open3d", "numpy"):
        try:
            m = importlib.import_module(mod)
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
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for k, v in info.items():
            print(f"{k:>14}: {v}")
    return 0
