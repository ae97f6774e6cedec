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
"""What `physdyn record` / the recorder node record and how: the options and RecorderConfig (see docs/bags.md).

ROS-free: the recorder itself (rclpy subscriptions, the recording loop, the `physdyn record` command's run) is
physdyn_ros.nodes.recorder_node, which takes its configuration from here.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from datetime import datetime

from .types import SUITE_TOPICS
from .writer import MiB, parse_size


@dataclass
class RecorderConfig:
    """What to record and how (the node's parameters of the same names)."""

    output: str = ""  # bag folder to create; "" = rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory
    topics: list[str] = field(default_factory=list)  # "name" or "name:pkg/msg/Type"; empty = the suite's topics
    storage: str = "mcap"  # or "sqlite3"
    split_duration: float = 10.0  # s of wall time per bag file (0 = no limit)
    split_size: int = 64 * MiB  # bytes per bag file (0 = no limit)
    max_bytes: int = 0  # stop cleanly before the bag exceeds this (0 = no limit)
    min_free: int = 64 * MiB  # refuse to start / stop cleanly below this much free disk space
    qos_depth: int = 1000  # subscription queue depth (bursts of this many messages are never dropped)
    max_duration: float = 0.0  # stop after this many seconds (0 = until a signal)
    discovery_period: float = 0.1  # s between looks at the graph for new publishers


def default_output() -> str:
    return datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("topics", nargs="*", metavar="TOPIC[:TYPE]",
                        help="topics to record, e.g. object_state or /tf:tf2_msgs/msg/TFMessage (default: the "
                             f"suite's topics: {', '.join(SUITE_TOPICS)})")
    parser.add_argument("-o", "--output", default="",
                        help="bag folder to create (must not exist or be empty; default rosbag2_<date>-<time>)")
    parser.add_argument("-s", "--storage", choices=["mcap", "sqlite3"], default="mcap", help="storage (mcap)")
    parser.add_argument("--split-duration", type=float, default=10.0, metavar="S",
                        help="start a new bag file every S seconds (default 10; a crash takes at most the "
                             "current file out of the bag, its chunks older than 1 s stay salvageable); 0 = never")
    parser.add_argument("--split-size", default="64M", metavar="BYTES",
                        help="start a new bag file once it holds this much (default 64M); 0 = no limit")
    parser.add_argument("--max-bytes", default="0", metavar="BYTES",
                        help="stop cleanly before the whole bag exceeds this size, e.g. 2G (default: no limit)")
    parser.add_argument("--min-free", default="64M", metavar="BYTES",
                        help="refuse to start, or stop cleanly, when the disk has less free space (default 64M)")
    parser.add_argument("--qos-depth", type=int, default=1000, help="subscription queue depth (default 1000)")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C / SIGTERM)")
    parser.add_argument("--use-sim-time", action="store_true",
                        help="stamp messages with the /clock time instead of the reception time")


def config_from_args(args: argparse.Namespace) -> RecorderConfig:
    """The RecorderConfig of `physdyn record`'s options (ValueError for a bad value, before anything starts)."""
    if args.split_duration < 0 or args.duration < 0:
        raise ValueError("--split-duration and --duration must not be negative")
    if args.qos_depth < 1:
        raise ValueError("--qos-depth must be at least 1")
    return RecorderConfig(output=args.output, topics=list(args.topics), storage=args.storage,
                          split_duration=args.split_duration, split_size=parse_size(args.split_size) or 0,
                          max_bytes=parse_size(args.max_bytes) or 0, min_free=parse_size(args.min_free) or 0,
                          qos_depth=args.qos_depth, max_duration=args.duration)
