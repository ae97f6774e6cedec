"""`physdyn record`: record the suite's topics (or `topic:type` ones) into a rosbag2 bag (see docs/bags.md)."""
from __future__ import annotations

import argparse

from .types import SUITE_TOPICS
from .writer import parse_size


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


def run(args: argparse.Namespace) -> int:
    from ..nodes.recorder_node import RecorderConfig, record

    if args.split_duration < 0 or args.duration < 0:
        raise ValueError("--split-duration and --duration must not be negative")
    if args.qos_depth < 1:
        raise ValueError("--qos-depth must be at least 1")
    config = RecorderConfig(output=args.output, topics=list(args.topics), storage=args.storage,
                            split_duration=args.split_duration, split_size=parse_size(args.split_size) or 0,
                            max_bytes=parse_size(args.max_bytes) or 0, min_free=parse_size(args.min_free) or 0,
                            qos_depth=args.qos_depth, max_duration=args.duration)
    ros_args = ["--ros-args", "-p", "use_sim_time:=true"] if args.use_sim_time else []
    return record(config, args=["physdyn-record", *ros_args], announce=lambda s: print(s, flush=True))

