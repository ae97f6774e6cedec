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
"""The ``physdyn`` command: one entry point, one subcommand per task.

Each subcommand lives in the module it drives; that module defines ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported only when their subcommand runs, so ``physdyn --help`` stays fast
and a machine without ROS can still train.

Errors: a user's mistake (see _user_error_types: a bad value, path or file, a storage stop, ...) ends with one
line `physdyn <cmd>: error: <reason>` on stderr and exit code 2, never a traceback (PHYSDYN_DEBUG=1 prints it
first); any other exception is a bug and propagates with its traceback (exit code 1).
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
from typing import Sequence

#: name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "generate": ("physdyn_ros.sim.generate", "simulate pushes with pybullet and write a dataset"),
    "train": ("physdyn_ros.learn.train", "train the dynamics model on a dataset"),
    "fit-topple": ("physdyn_ros.learn.topple_fit", "fit a checkpoint's whole-push topple head (frozen dynamics)"),
    "fit-topple-fusion": ("physdyn_ros.topple_fusion_fit", "fit a checkpoint's fusion of its topple head and "
                          "physics on the whole cloud's solid"),
    "fit-spread": ("physdyn_ros.spread_fit", "calibrate a checkpoint's rest-pose spread (radii of stated coverage)"),
    "evaluate": ("physdyn_ros.learn.evaluate", "evaluate a checkpoint and the baselines on a test split"),
    "predict": ("physdyn_ros.predict_cli", "roll out a checkpoint for one cloud and initial velocity"),
    "plan": ("physdyn_ros.planning.cli", "plan a push to a goal pose with the model; execute it in pybullet"),
    "up": ("physdyn_ros.launcher", "start the node suite (sim, perception, predictor) with config/ parameters"),
    "demo": ("physdyn_ros.demo", "start the suite, push objects, compare predicted and true motion"),
    "info": ("physdyn_ros.info", "print the installation: interfaces, shipped model, versions"),
    "record": ("physdyn_ros.nodes.recorder_node", "record the suite's topics into a rosbag2 bag (MCAP, split files)"),
    "replay": ("physdyn_ros.ros.replay", "publish a recorded bag with its original timing"),
    "report": ("physdyn_ros.bag.report", "predicted vs observed pushes of a bag: errors and a top-view PNG"),
    "bag2dataset": ("physdyn_ros.bag.bag2dataset", "turn recorded pushes into a dataset for fine-tuning"),
}


class UsageError(Exception):
    """A bad command-line input; printed as one line, exit code 2."""


#: Set to 1 to see the traceback of a user error too (the one-line error still ends the output).
DEBUG_ENV = "PHYSDYN_DEBUG"


def _user_error_types() -> tuple[type[BaseException], ...]:
    """Exceptions that mean "the input is wrong" (or the environment refused it), not "physdyn has a bug".

    ValueError is how the subcommands refuse a bad value, path or file content (the bag, dataset, checkpoint and
    planner errors derive from it); OSError covers missing / unreadable / unwritable paths and full disks;
    RuntimeError is raised for failures of the running system (checkpoint errors, storage stops, nodes that do
    not start). Library errors that name a bad input file are listed too, in case one escapes a subcommand.
    """
    types: list[type[BaseException]] = [UsageError, ValueError, OSError, RuntimeError]
    for module, names in (("rosbags.rosbag2", ("ReaderError", "WriterError")), ("yaml", ("YAMLError",)),
                          ("ruamel.yaml", ("YAMLError",))):
        if module.split(".")[0] in sys.modules:  # only libraries the command loaded can have raised
            try:
                mod = importlib.import_module(module)
            except ImportError:
                continue
            types += [getattr(mod, n) for n in names if isinstance(getattr(mod, n, None), type)]
    return tuple(types)


def error_message(exc: BaseException) -> str:
    """One line naming the problem: the exception's message, or for a bare OSError 'path: reason'."""
    if isinstance(exc, OSError) and exc.strerror and len(exc.args) >= 2:
        where = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        text = f"{where}: {exc.strerror}" if where else exc.strerror
    else:
        text = str(exc)
    text = " ".join(text.split())  # a multi-line message (YAML errors, ...) on one line
    return text or type(exc).__name__


def _top_parser() -> argparse.ArgumentParser:
    lines = "\n".join(f"  {name:<10} {text}" for name, (_, text) in COMMANDS.items())
    parser = argparse.ArgumentParser(
        prog="physdyn",
        description="physdyn_ros: predict how pushed objects move from their 3D shape.",
        epilog=f"commands:\n{lines}\n\nRun 'physdyn COMMAND --help' for the options of a command.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("command", choices=sorted(COMMANDS), metavar="COMMAND", help="what to do")
    parser.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser().parse_args(argv[:1])
    module_name, text = COMMANDS[top.command]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"physdyn {top.command}", description=text)
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        print(f"physdyn {top.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - sorted below: a user's mistake or a bug
        if not isinstance(exc, _user_error_types()):
            raise  # a bug: the traceback is what a report needs
        # A user's mistake: one readable line naming the problem instead of a traceback (PHYSDYN_DEBUG=1 shows it).
        if os.environ.get(DEBUG_ENV, "").strip() not in ("", "0"):
            traceback.print_exc()
        print(f"physdyn {top.command}: error: {error_message(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
