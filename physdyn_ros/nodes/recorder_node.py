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
"""Recorder: the suite's topics (or any `topic:type`) -> a rosbag2 bag, without decoding a single message.

Subscriptions are raw (`raw=True`): the CDR bytes DDS delivers are written as they are, with their receive time
(the rmw's reception timestamp; the node clock when use_sim_time is set). Like `ros2 bag record`, a topic is
subscribed once a publisher appears, with a QoS adapted to the publishers (reliable if all of them are,
transient local if all of them are) and a deep queue, and the publishers' offered QoS goes into the bag.

The subscriptions keep every sample (KEEP_ALL): when the recorder falls behind a burst, reliable DDS holds the
publishers back instead of dropping what does not fit in a keep-last queue.

Stopping: SIGINT / SIGTERM (Ctrl-C) or max_duration end the recording cleanly: nothing published before the
stop is lost. The node first takes what DDS already delivered. A reliable sample the transport dropped during a
burst is re-sent only after the publisher's next heartbeat (Fast DDS: every 3 s), so a topic whose latest
message was sent less than REPAIR_WAIT before the stop is waited for until a message sent after the stop
arrives (with one publisher per topic, reliable delivery is in order: everything before it is in) or until
REPAIR_WAIT has passed since its latest message. A stop therefore takes at most REPAIR_WAIT + 0.3 s; messages
that arrive meanwhile are recorded too. A second signal skips the wait. Crash bounds, layout: bag/writer.py.

    ros2 run physdyn_ros recorder_node --ros-args -p output:=run1 -p topics:="['object_state']"
    physdyn record -o run1 object_state cloud /tf:tf2_msgs/msg/TFMessage
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.signals import SignalHandlerOptions
from rclpy.validate_topic_name import validate_topic_name
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from ..bag.record import RecorderConfig, add_arguments, config_from_args, default_output
from ..bag.types import SUITE_TOPICS, ensure_type
from ..bag.writer import MiB, BagStorageError, BagWriter
from ..ros.diagnostics import ERROR, OK, WARN, Diagnostics, Report
from ..ros.messages import message_class
from ..ros.params import declare

#: `physdyn record` (physdyn_ros.cli) runs this module: add_arguments (the ROS-free options) and run below.
__all__ = ["RecorderConfig", "RecorderNode", "add_arguments", "default_output", "main", "message_class",
           "parse_topics", "record", "run"]

#: After a stop request, keep taking messages until this long without one ...
DRAIN_IDLE = 0.3
#: ... and, for topics that published this recently, until a message sent after the stop arrives or this long
#: after their latest one: a reliable sample lost in transport is repaired at the publisher's next heartbeat
#: (Fast DDS's default heartbeat period is 3 s).
REPAIR_WAIT = 3.2


def parse_topics(specs: list[str]) -> dict[str, str | None]:
    """['name', 'name:pkg/msg/Type', ...] -> {name: type or None (take the type from the publishers)}.

    Suite topic names get their known type. ValueError for a bad name or an unknown type, before recording.
    """
    out: dict[str, str | None] = {}
    for spec in specs or list(SUITE_TOPICS):
        name, sep, msgtype = str(spec).strip().partition(":")
        name = name.strip()
        if not name:
            raise ValueError(f"bad topic {spec!r}: expected NAME or NAME:package/msg/Type")
        try:
            validate_topic_name(name)
        except Exception as exc:  # noqa: BLE001 - rclpy raises its own InvalidTopicNameException
            raise ValueError(f"bad topic name {name!r}: {str(exc).splitlines()[0].rstrip(':')}") from None
        if sep:
            msgtype = ensure_type(msgtype)  # the typestore must be able to describe it in the bag
            message_class(msgtype)
        else:
            msgtype = SUITE_TOPICS.get(name.lstrip("/"))
        out[name] = msgtype
    return out


def rosbags_qos(profile: QoSProfile) -> Qos:
    """An offered rclpy QoS profile (from the graph) as rosbags writes it into metadata.yaml and MCAP."""

    def t(d) -> QosTime:
        ns = int(d.nanoseconds)
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)

    return Qos(QosHistory(int(profile.history)), int(profile.depth), QosReliability(int(profile.reliability)),
               QosDurability(int(profile.durability)), t(profile.deadline), t(profile.lifespan),
               QosLiveliness(int(profile.liveliness)), t(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def adapted_qos(offered: list[QoSProfile], depth: int) -> QoSProfile:
    """A subscription QoS compatible with every publisher, as reliable / durable as all of them allow."""
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class RecorderNode(Node):
    """Subscribes raw to the topics as their publishers appear and writes everything into a BagWriter."""

    def __init__(self, config: RecorderConfig | None = None, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        c = config or RecorderConfig()
        cfg = RecorderConfig(
            output=declare(self, "output", c.output or default_output(), "bag folder to create (must not exist "
                           "or be empty)", read_only=True),
            topics=declare(self, "topics", list(c.topics) or list(SUITE_TOPICS), "topics to record: NAME (type "
                           "from the suite or the publishers) or NAME:package/msg/Type", read_only=True),
            storage=declare(self, "storage", c.storage, "bag storage", read_only=True, choices=("mcap", "sqlite3")),
            split_duration=declare(self, "split_duration", float(c.split_duration), "s of wall time per bag file "
                                   "(bounds what a crash loses); 0 = no limit", read_only=True, low=0.0),
            split_size=declare(self, "split_size", int(c.split_size), "bytes per bag file; 0 = no limit",
                               read_only=True, low=0),
            max_bytes=declare(self, "max_bytes", int(c.max_bytes), "stop cleanly before the bag exceeds this "
                              "many bytes; 0 = no limit", read_only=True, low=0),
            min_free=declare(self, "min_free", int(c.min_free), "refuse to start / stop cleanly when the disk "
                             "has fewer free bytes", read_only=True, low=0),
            qos_depth=declare(self, "qos_depth", int(c.qos_depth), "subscription queue depth", read_only=True,
                              low=1, high=1_000_000),
            max_duration=declare(self, "max_duration", float(c.max_duration), "stop after this many seconds; "
                                 "0 = until SIGINT/SIGTERM", read_only=True, low=0.0),
            discovery_period=c.discovery_period)
        self.config = cfg
        self.use_sim_time = bool(self.get_parameter("use_sim_time").value)
        wanted = parse_topics(cfg.topics)
        self.pending: dict[str, str | None] = {self.resolve_topic_name(n): t for n, t in wanted.items()}
        self.writer = BagWriter(cfg.output, storage=cfg.storage, split_duration=cfg.split_duration or None,
                                split_size=cfg.split_size or None, max_bytes=cfg.max_bytes or None,
                                min_free=cfg.min_free)
        self.writer.open()
        self.subs: dict[str, object] = {}
        self.failure: str | None = None
        self.received = 0
        self.receiving: set[int] = set()  # topic ids with at least one message: their publishers are matched
        self.lost = 0
        self.last_rx = time.monotonic()
        self.last_sent: dict[int, int] = {}  # topic id -> latest source timestamp (ns, publisher clock)
        self._warned: set[str] = set()
        self._next_poll = 0.0
        self.diagnostics = Diagnostics(self, "recording", self._diagnose)
        self.poll()

    def _diagnose(self) -> Report:
        level = ERROR if self.failure else WARN if self.lost else OK
        message = self.failure or (f"{self.lost} message(s) lost" if self.lost else f"recording to {self.writer.path}")
        return level, message, {"bag": str(self.writer.path), "topics_recording": len(self.subs),
                                "topics_waiting": len(self.pending), "topics_receiving": len(self.receiving),
                                "received": self.received, "lost": self.lost,
                                "written": self.writer.message_count}

    # ---------------------------------------------------------------------------------------------- discovery
    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def poll(self) -> None:
        """Subscribe to topics whose publishers appeared; finish bag files that are due. Called from the loop."""
        now = time.monotonic()
        if now < self._next_poll:
            return
        self._next_poll = now + self.config.discovery_period
        for name, want in list(self.pending.items()):
            infos = self.get_publishers_info_by_topic(name)
            if not infos:
                continue
            types = sorted({i.topic_type for i in infos})
            msgtype = want
            if msgtype is None:
                if len(types) > 1:
                    self._warn_once(name, f"not recording {name}: publishers disagree on its type {types}")
                    continue
                try:
                    msgtype = ensure_type(types[0])
                    message_class(msgtype)
                except ValueError as exc:
                    self._warn_once(name, f"not recording {name}: {exc}")
                    del self.pending[name]
                    continue
            infos = [i for i in infos if i.topic_type == msgtype]
            if not infos:
                self._warn_once(name, f"{name}: publishers have type {types}, not {msgtype}; waiting for a "
                                      f"publisher of {msgtype}")
                continue
            offered = [i.qos_profile for i in infos]
            tid = self.writer.add_topic(name, msgtype, [rosbags_qos(p) for p in offered])
            qos = adapted_qos(offered, self.config.qos_depth)
            events = SubscriptionEventCallbacks(
                incompatible_qos=lambda e, n=name: self._warn_once(
                    f"qos:{n}", f"{n}: a publisher's QoS is incompatible with the recorder's subscription "
                                f"(policy {e.last_policy_kind}); its messages are not recorded"),
                message_lost=lambda e, n=name: self._on_lost(n, e.total_count_change))
            self.subs[name] = self.create_subscription(message_class(msgtype), name, self._callback(tid), qos,
                                                       raw=True, event_callbacks=events)
            del self.pending[name]
            self.get_logger().info(f"recording {name} ({msgtype}, {len(infos)} publisher(s), "
                                   f"{qos.reliability.name.lower()}, {qos.durability.name.lower()})")
        try:
            self.writer.tick()
        except BagStorageError as exc:
            self.failure = self.failure or str(exc)

    def _on_lost(self, name: str, count: int) -> None:
        self.lost += int(count)
        self.get_logger().warning(f"{name}: DDS reports {count} message(s) lost before reaching the recorder")

    def _callback(self, tid: int) -> Callable[[bytes, dict], None]:
        def on_message(data: bytes, info: dict) -> None:
            if self.failure is not None:
                return
            if self.use_sim_time:
                stamp = self.get_clock().now().nanoseconds
            else:  # the middleware's reception time: exact even when the executor runs late
                stamp = int(info.get("received_timestamp") or 0) or time.time_ns()
            try:
                self.writer.write(tid, stamp, data)
            except BagStorageError as exc:
                self.failure = str(exc)
                return
            self.received += 1
            self.receiving.add(tid)
            self.last_rx = time.monotonic()
            sent = int(info.get("source_timestamp") or 0)
            if sent > self.last_sent.get(tid, 0):
                self.last_sent[tid] = sent
        return on_message

    def awaiting_repair(self, stop_ns: int) -> bool:
        """Whether a topic published shortly before the stop and nothing sent after the stop has arrived yet."""
        now = time.time_ns()
        wait = int(REPAIR_WAIT * 1e9)
        return any(stop_ns - wait <= sent <= stop_ns and now < sent + wait for sent in self.last_sent.values())

    def summary(self) -> str:
        w = self.writer
        lost = f", {self.lost} lost in DDS" if self.lost else ""
        return (f"bag {w.path}: {w.message_count} messages on {sum(1 for t in w.topics)} topic(s) in "
                f"{len(w.files)} file(s){lost}")


def record(config: RecorderConfig | None = None, args: list[str] | None = None,
           announce: Callable[[str], None] = print) -> int:
    """Run the recorder until SIGINT/SIGTERM or max_duration; returns 0, raises on a refusal or storage stop."""
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    hurry = threading.Event()
    stop_time = [0.0]
    stop_ns = [0]
    previous: dict[int, object] = {}

    def on_signal(signum, frame) -> None:  # noqa: ARG001
        if stop.is_set():
            hurry.set()
            return
        stop_time[0], stop_ns[0] = time.monotonic(), time.time_ns()
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            previous[s] = signal.signal(s, on_signal)
    node: RecorderNode | None = None
    executor = SingleThreadedExecutor()
    try:
        node = RecorderNode(config)
        executor.add_node(node)
        cfg = node.config
        announce(f"recording {len(node.pending) + len(node.subs)} topic(s) to {node.writer.path} "
                 f"({cfg.storage}, files of {cfg.split_duration or 'unlimited'} s / "
                 f"{(cfg.split_size / MiB) if cfg.split_size else 'unlimited'} MiB); Ctrl-C to stop")
        end = time.monotonic() + cfg.max_duration if cfg.max_duration > 0 else float("inf")
        while not stop.is_set() and node.failure is None:
            executor.spin_once(timeout_sec=0.05)
            node.poll()
            if time.monotonic() >= end and not stop.is_set():
                stop_time[0], stop_ns[0] = time.monotonic(), time.time_ns()
                stop.set()
        # Drain: take what DDS has delivered or is still repairing, so a stop during a burst loses nothing.
        t_max = stop_time[0] + REPAIR_WAIT + DRAIN_IDLE
        while node.failure is None and not hurry.is_set() and time.monotonic() < t_max:
            executor.spin_once(timeout_sec=0.05)
            idle = time.monotonic() - max(node.last_rx, stop_time[0]) >= DRAIN_IDLE
            if idle and not node.awaiting_repair(stop_ns[0]):
                break
    finally:
        failure = None
        if node is not None:
            try:
                node.writer.close()
            except BagStorageError as exc:
                node.failure = node.failure or str(exc)
            failure = node.failure
            announce(node.summary())
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for s, h in previous.items():
            signal.signal(s, h)
    if failure:
        raise BagStorageError(failure)
    return 0


def run(args: argparse.Namespace) -> int:
    """`physdyn record [TOPIC[:TYPE] ...] [-o BAG] ...`: the recorder with the command line's options."""
    config = config_from_args(args)
    ros_args = ["--ros-args", "-p", "use_sim_time:=true"] if args.use_sim_time else []
    return record(config, args=["physdyn-record", *ros_args], announce=lambda s: print(s, flush=True))


def main(args: list[str] | None = None) -> int:
    """`ros2 run physdyn_ros recorder_node --ros-args -p output:=... -p topics:=[...]`"""
    try:
        return record(None, args=args)
    except Exception as exc:  # noqa: BLE001 - a refusal or a storage stop: say why, exit non-zero
        print(f"recorder: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
