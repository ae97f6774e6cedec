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
"""`physdyn replay BAG`: publish a bag's messages with their recorded timing (or --rate times faster).

Messages are published serialized: the recorded CDR bytes go to the middleware as they are (rclpy's
publish(bytes) -> publish_raw), through a publisher of the real type so that subscribers match. Each topic is
offered with the QoS its publishers offered when it was recorded (reliable / transient local only if all of
them were, as `ros2 bag play` does). Message i is sent at start + (t_i - t_0) / rate, t being the recording's
receive timestamps; the schedule is absolute, so sleeping jitter never accumulates.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosbags.interfaces import QosDurability, QosReliability

from ..bag.reading import check_bag, open_bag
from .messages import message_class

#: Publisher queue depth: deep enough that a burst is never overwritten before the middleware sends it.
PUB_DEPTH = 1000
#: Longest wait, per topic, for subscribers to acknowledge the last messages before the replay returns.
ACK_TIMEOUT_S = 2.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", help="bag folder (or a single .mcap / .db3 file)")
    parser.add_argument("--rate", type=float, default=1.0, help="speed factor (2 = twice as fast; default 1)")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics (default: all)")
    parser.add_argument("--delay", type=float, default=2.0, metavar="S",
                        help="before publishing, wait up to S seconds until every topic has a subscriber "
                             "(default 2; 0 = start at once)")
    parser.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds of the bag")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def _topic(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def replay(bag: str | Path, rate: float = 1.0, topics: list[str] | None = None, delay: float = 2.0,
           start: float = 0.0, node=None, log=print) -> dict:
    """Publish the bag (rclpy must be initialised; `node` None creates one). Returns counts and timing."""
    if not rate > 0:
        raise ValueError(f"--rate must be positive, got {rate}")
    if delay < 0 or start < 0:
        raise ValueError("--delay and --start must not be negative")
    bag = check_bag(bag)  # before creating a node: FileNotFoundError / BagError for a path that is not a bag
    own = node is None
    if own:
        node = rclpy.create_node("replay")
    try:
        with open_bag(bag) as reader:
            conns = list(reader.connections)
            if topics:
                want = {_topic(t) for t in topics}
                missing = want - {c.topic for c in conns}
                if missing:
                    raise ValueError(f"topics {sorted(missing)} are not in {bag} (it has "
                                     f"{sorted({c.topic for c in conns})})")
                conns = [c for c in conns if c.topic in want]
            publishers: dict[str, object] = {}
            for c in conns:
                if c.topic in publishers:
                    continue
                offers = list(c.ext.offered_qos_profiles)
                reliable = bool(offers) and all(q.reliability == QosReliability.RELIABLE for q in offers)
                latched = bool(offers) and all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offers)
                qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUB_DEPTH,
                                 reliability=ReliabilityPolicy.RELIABLE if reliable or not offers
                                 else ReliabilityPolicy.BEST_EFFORT,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                                 else DurabilityPolicy.VOLATILE)
                try:
                    cls = message_class(c.msgtype)
                except ValueError as exc:
                    if topics:  # asked for explicitly: refuse
                        raise
                    log(f"skipping {c.topic}: {exc}")
                    continue
                publishers[c.topic] = node.create_publisher(cls, c.topic, qos)
            conns = [c for c in conns if c.topic in publishers]
            if not conns:
                raise ValueError(f"nothing to replay: {bag} has no messages of a type this machine can publish")
            # Discovery takes a moment (about 1 s across processes): messages sent before a subscriber matched
            # are lost for it, so wait until every topic has one (or the delay is over).
            deadline = time.monotonic() + delay
            while time.monotonic() < deadline and not all(p.get_subscription_count() for p in publishers.values()):
                time.sleep(0.02)
            t_first = reader.start_time + int(start * 1e9)
            count = 0
            wall0 = None
            for conn, stamp, data in reader.messages(connections=conns, start=t_first):
                if wall0 is None:
                    wall0, t0 = time.monotonic(), stamp
                due = wall0 + (stamp - t0) / 1e9 / rate
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                publishers[conn.topic].publish(bytes(data))
                count += 1
            elapsed = time.monotonic() - wall0 if wall0 is not None else 0.0
            # A reliable writer destroyed right after its last publish can take that message with it (measured:
            # the last of 40 states lost now and then): wait, bounded, until the subscribers acknowledged all.
            for pub in publishers.values():
                pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
    finally:
        if own:
            node.destroy_node()
    log(f"replayed {count} messages on {len(publishers)} topic(s) in {elapsed:.2f} s (rate {rate:g})")
    return {"messages": count, "topics": sorted(publishers), "seconds": elapsed}


def run(args: argparse.Namespace) -> int:
    # Plain KeyboardInterrupt on Ctrl-C (the cli prints "interrupted"); rclpy is shut down in any case.
    rclpy.init(args=["physdyn-replay"], signal_handler_options=SignalHandlerOptions.NO)
    try:
        replay(args.bag, rate=args.rate, topics=args.topics, delay=args.delay, start=args.start,
               log=(lambda s: None) if args.quiet else print)
    finally:
        rclpy.try_shutdown()
    return 0
