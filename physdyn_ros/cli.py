"""The ``physdyn`` command: one entry point, one subcommand per task.

Each subcommand lives in the module it drives; that module defines ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported only when their subcommand runs, so ``physdyn --help`` stays fast
and a machine without ROS can still train.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

#: name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "generate": ("physdyn_ros.sim.generate", "simulate pushes with pybullet and write a dataset"),
    "train": ("physdyn_ros.learn.train", "train the dynamics model on a dataset"),
    "evaluate": ("physdyn_ros.learn.evaluate", "evaluate a checkpoint and the baselines on a test split"),
    "predict": ("physdyn_ros.predictor", "roll out a checkpoint for one cloud and initial velocity"),
    "plan": ("physdyn_ros.planning.cli", "plan a push to a goal pose with the model; execute it in pybullet"),
    "up": ("physdyn_ros.launcher", "start the node suite (sim, perception, predictor) with config/ parameters"),
    "demo": ("physdyn_ros.demo", "start the suite, push objects, compare predicted and true motion"),
    "info": ("physdyn_ros.info", "print the installation: interfaces, shipped model, versions"),
    "record": ("physdyn_ros.bag.record", "record the suite's topics into a rosbag2 bag (MCAP, split files)"),
    "replay": ("physdyn_ros.bag.replay", "publish a recorded bag with its original timing"),
    "report": ("physdyn_ros.bag.report", "predicted vs observed pushes of a bag: errors and a top-view PNG"),
    "bag2dataset": ("physdyn_ros.bag.bag2dataset", "turn recorded pushes into a dataset for fine-tuning"),
}


class UsageError(Exception):
    """A bad command-line input; printed as one line, exit code 2."""


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
    except (UsageError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError,
            PermissionError, RuntimeError) as exc:
        # One readable line instead of a traceback; the exception names the problem.
        print(f"physdyn {top.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
