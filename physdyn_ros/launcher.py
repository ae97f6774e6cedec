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
"""``physdyn up``: start the node suite (sim, perception, predictor) as subprocesses with one params file.

The same nodes, names and params file as launch/physdyn.launch.py, for machines without `ros2 launch`:
    python -m physdyn_ros.nodes.<executable> --ros-args --params-file <config> [--params-file <overrides>]
A user's overrides (--param NODE:NAME:=VALUE, --model, --real-time-factor ...) go into a second params file
under the node's own section, because rclpy ranks a node's section of a params file above `-p name:=value`
(which applies to `/**`): passed as -p they were silently dropped for every name that config/suite.yaml sets.
An override of a parameter the node does not have is refused before anything starts.
Dense clouds: unless FASTRTPS_ or FASTDDS_DEFAULT_PROFILES_FILE is set, both point the nodes at config/fastdds.xml
(a 16 MB shared-memory segment: Fast DDS's 512 KB default loses 100k-point clouds between processes).
Each node's output is forwarded with its name in front (or written to a log folder). Ctrl-C, SIGTERM or SIGHUP
stops every node (SIGINT: rclpy shuts down cleanly); a node that exits stops the others, and the command exits
non-zero naming it. The suite is ready when every node's <node>/get_state answers "active" ("unconfigured"
with --no-autostart, for a lifecycle manager); a second suite of the same nodes, domain and namespace is refused.
"""
from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Any, Mapping, Sequence

from .conventions import PARENT_PID_ENV
from .suite import (CONFIG_NAME, DDS_PROFILE_VARS, GOAL_STATE, NODES, SPECS, default_config, dds_profile_env,
                    parse_overrides, state_source_overlay, write_overrides)


#: launch/physdyn.launch.py's arguments and the `physdyn up` options that do the same (a test keeps them in step).
LAUNCH_ARGUMENTS = {"params_file": "--config", "use_sim": "--no-sim", "namespace": "--namespace",
                    "use_sim_time": "--use-sim-time", "log_level": "--log-level", "dds_profile": "--dds-profile",
                    "autostart": "--no-autostart", "state_source": "--state-source"}


def node_command(executable: str, params_file: Path, overrides_file: Path | None = None,
                 log_level: str | None = None, namespace: str = "") -> list[str]:
    cmd = [sys.executable, "-m", f"physdyn_ros.nodes.{executable}", "--ros-args", "--params-file", str(params_file)]
    if overrides_file is not None:
        cmd += ["--params-file", str(overrides_file)]
    if namespace:
        cmd += ["-r", f"__ns:={namespace}"]
    if log_level:
        cmd += ["--log-level", log_level]
    return cmd


class LifecycleProbe:
    """Asks managed nodes for their lifecycle state through <namespace>/<node>/get_state (lifecycle_msgs/srv/
    GetState), from a private rclpy context on the nodes' ROS_DOMAIN_ID (it leaves the caller's rclpy alone and
    installs no signal handler)."""

    #: s after which an unanswered request is sent again (a request sent before discovery completes is lost)
    RESEND = 2.0

    def __init__(self, names: Sequence[str], namespace: str = "", env: Mapping[str, str] | None = None) -> None:
        import rclpy
        from lifecycle_msgs.srv import GetState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        env = os.environ if env is None else env
        self._request = GetState.Request
        self.context = rclpy.Context()
        # args=[]: rcl would otherwise read this process's own command line (physdyn up's --param NODE:NAME:=V
        # looks like a deprecated remap rule to it).
        rclpy.init(args=[], context=self.context, domain_id=int(env.get("ROS_DOMAIN_ID", "").strip() or 0),
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f"physdyn_up_probe_{os.getpid()}", context=self.context, enable_rosout=False,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.namespace = namespace or "/"
        self.clients = {n: self.node.create_client(GetState, f"{namespace}/{n}/get_state") for n in names}
        self.states: dict[str, str] = {}
        self._pending: dict[str, tuple[Any, float]] = {}

    def poll(self, names: Sequence[str] | None = None, timeout: float = 0.1) -> dict[str, str]:
        """Ask `names` (default: all) for their state, spin up to `timeout` s; the states known so far."""
        now = time.monotonic()
        for name in names if names is not None else list(self.clients):
            future, sent = self._pending.get(name, (None, 0.0))
            if future is not None and future.done():
                result = future.result()
                if result is not None:
                    self.states[name] = result.current_state.label
                future = None
            elif future is not None and now - sent > self.RESEND:
                self.clients[name].remove_pending_request(future)
                future = None
            if future is None:
                self._pending.pop(name, None)
                if self.clients[name].service_is_ready():
                    self._pending[name] = (self.clients[name].call_async(self._request()), now)
        self.executor.spin_once(timeout_sec=timeout)
        for name, (future, _) in list(self._pending.items()):
            if future.done() and future.result() is not None:
                self.states[name] = future.result().current_state.label
                del self._pending[name]
        return dict(self.states)

    def running(self, timeout: float = 1.5, answer_timeout: float = 6.0) -> list[str]:
        """The names among this probe's nodes that some process already runs in its namespace: on the graph
        within `timeout` s and answering get_state within `answer_timeout` s of the start (a name the graph still
        lists for a node that is gone, or one that does not spin, is not a running node; a loaded machine may take
        seconds to answer, an empty graph returns after `timeout`)."""
        t0 = time.monotonic()
        while True:
            present = [n for n, ns in self.node.get_node_names_and_namespaces()
                       if n in self.clients and ns.rstrip("/") == self.namespace.rstrip("/")]
            if present:
                self.poll(present, timeout=0.1)
            else:
                self.executor.spin_once(timeout_sec=0.1)
            answered = sorted(n for n in present if n in self.states)
            waited = time.monotonic() - t0
            if (present and len(answered) == len(present)) or waited >= (answer_timeout if present else timeout):
                return answered

    def close(self) -> None:
        import rclpy

        for name, (future, _) in self._pending.items():
            self.clients[name].remove_pending_request(future)
        self._pending.clear()
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class NodeProcess:
    """One node subprocess whose output is forwarded by a thread."""

    def __init__(self, name: str, cmd: list[str], out: IO[str], env: dict[str, str]) -> None:
        self.name, self.cmd, self.out = name, cmd, out
        # Own session: a terminal's Ctrl-C reaches only the launcher, which forwards it exactly once.
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     env=env, start_new_session=True)
        self.thread = threading.Thread(target=self._pump, name=f"out-{name}", daemon=True)
        self.thread.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                self.out.write(f"[{self.name}] {line}" if self.out in (sys.stdout, sys.stderr) else line)
                self.out.flush()
            except ValueError:  # output closed while stopping
                pass

    def poll(self) -> int | None:
        return self.proc.poll()

    def interrupt(self, sig: int = signal.SIGINT) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)


class Suite:
    """The running nodes. Use as a context manager, or call start() / wait_ready() / stop().

    autostart False starts the managed nodes unconfigured (parameter autostart:=false), for a lifecycle manager;
    wait_ready() then waits until each one answers get_state (unconfigured)."""

    def __init__(self, config: Path | None = None, overrides: dict[str, Sequence[str]] | None = None,
                 nodes: Sequence[str] | None = None, log_dir: Path | None = None, log_level: str | None = None,
                 env: dict[str, str] | None = None, namespace: str = "", autostart: bool = True) -> None:
        self.config = Path(config) if config else default_config()
        if not self.config.is_file():
            raise FileNotFoundError(f"params file {self.config} does not exist")
        self.overrides = {n: list(v) for n, v in (overrides or {}).items()}
        self.autostart = bool(autostart)
        if not self.autostart:
            for spec in SPECS:
                self.overrides.setdefault(spec.name, []).append("autostart:=false")
        wanted = list(nodes) if nodes else [n for n, _ in NODES]
        unknown = sorted(set(wanted) - {n for n, _ in NODES})
        if unknown:
            raise ValueError(f"unknown node(s) {unknown}; the suite has {[n for n, _ in NODES]}")
        self.nodes = [(n, e) for n, e in NODES if n in wanted]
        stray = sorted(set(self.overrides) - {n for n, _ in NODES})
        if stray:
            raise ValueError(f"parameter overrides for unknown node(s) {stray}")
        # Parsed and checked now: a bad override stops everything before a node starts.
        self.values = {n: parse_overrides(n, self.overrides[n]) for n, _ in self.nodes if self.overrides.get(n)}
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._locks: list[IO[str]] = []  # this machine's lock of each node (start() to stop())
        self.log_dir, self.log_level = log_dir, log_level
        if namespace and not re.fullmatch(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*", namespace):
            raise ValueError(f"namespace {namespace!r} is not a ROS namespace (letters, digits, _ and /)")
        self.namespace = ("/" + namespace.lstrip("/")) if namespace else ""
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.env.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "0")
        self.env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
        self.env[PARENT_PID_ENV] = str(os.getpid())  # the nodes stop when this process is gone
        self.dds_profile = dds_profile_env(self.env)
        self.procs: list[NodeProcess] = []
        self._files: list[IO[str]] = []
        #: the lifecycle state of each node, as its get_state service last answered (wait_ready)
        self.states: dict[str, str] = {}

    def already_running(self, timeout: float = 1.5) -> list[str]:
        """The suite's nodes that another process already runs on this ROS domain and namespace."""
        probe = LifecycleProbe([n for n, _ in self.nodes], self.namespace, self.env)
        try:
            return probe.running(timeout)
        finally:
            probe.close()

    def start(self, check_running: bool = True) -> "Suite":
        """Start the node processes; RuntimeError (nothing started) when `check_running` finds any of them
        already running on this domain and namespace (two of a node would answer every request twice)."""
        if check_running:
            domain = self.env.get("ROS_DOMAIN_ID", "").strip() or "0"
            # On this machine a lock per node says so at once; the graph probe finds the rest (ros2 launch,
            # other machines) once discovery has seen them.
            running = self._lock_nodes(domain) or self.already_running()
            if running:
                self._unlock_nodes()
                raise RuntimeError(f"node(s) {', '.join(running)} already run on ROS_DOMAIN_ID {domain} in namespace "
                                   f"'{self.namespace or '/'}': stop that suite first, or use another "
                                   "ROS_DOMAIN_ID or --namespace")
        if self.values:
            self._tmp = tempfile.TemporaryDirectory(prefix="physdyn_up_")
        for name, exe in self.nodes:
            if self.log_dir is not None:
                self.log_dir.mkdir(parents=True, exist_ok=True)
                out: IO[str] = open(self.log_dir / f"{name}.log", "w")
                self._files.append(out)
            else:
                out = sys.stdout
            extra = write_overrides(name, self.values[name], Path(self._tmp.name)) if name in self.values else None
            cmd = node_command(exe, self.config, extra, self.log_level, self.namespace)
            self.procs.append(NodeProcess(name, cmd, out, self.env))
        return self

    def dead(self) -> NodeProcess | None:
        return next((p for p in self.procs if p.poll() is not None), None)

    def wait_ready(self, timeout: float = 180.0, stop: threading.Event | None = None) -> bool:
        """Block until every node's get_state service answers "active" (autostart) or "unconfigured" (autostart
        off). RuntimeError if a node exits first or time runs out; False if `stop` was set first."""
        goal = GOAL_STATE[self.autostart]
        deadline = time.monotonic() + timeout
        probe = LifecycleProbe([p.name for p in self.procs], self.namespace, self.env)
        try:
            while True:
                waiting = [p.name for p in self.procs if self.states.get(p.name) != goal]
                if not waiting:
                    return True
                if stop is not None and stop.is_set():
                    return False
                d = self.dead()
                if d is not None:
                    d.thread.join(2.0)  # let its last lines (the reason) through
                    raise RuntimeError(f"node '{d.name}' exited with code {d.poll()} during start-up"
                                       + (f" (log: {self.log_dir / (d.name + '.log')})" if self.log_dir else ""))
                if time.monotonic() > deadline:
                    states = ", ".join(f"{n}: {self.states.get(n, 'no answer from get_state')}" for n in waiting)
                    raise RuntimeError(f"node(s) {waiting} not {goal} after {timeout:.0f} s ({states})")
                self.states.update(probe.poll(waiting))
        finally:
            probe.close()

    def _lock_nodes(self, domain: str) -> list[str]:
        """Take this machine's lock of each node of the suite on this domain and namespace (released with the
        process, even on SIGKILL); the names whose lock another process holds."""
        import fcntl

        held = []
        for name, _ in self.nodes:
            key = re.sub(r"[^A-Za-z0-9_]", "_", f"{domain}{self.namespace}_{name}")
            f = open(Path(tempfile.gettempdir()) / f"physdyn_up_{key}.lock", "a")
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.close()
                held.append(name)
                continue
            self._locks.append(f)
        return held

    def _unlock_nodes(self) -> None:
        for f in self._locks:
            f.close()  # closing the file releases its flock
        self._locks.clear()

    def stop(self, timeout: float = 10.0) -> dict[str, int | None]:
        """SIGINT every node, then SIGTERM / SIGKILL the ones that linger. Returns the exit codes.

        A node that has not answered get_state yet may still be importing (before rclpy's signal handlers): it
        gets SIGTERM, which ends it without a KeyboardInterrupt traceback."""
        for p in self.procs:
            p.interrupt(signal.SIGINT if p.name in self.states else signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for p in self.procs:
            try:
                p.proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.proc.terminate()
                try:
                    p.proc.wait(3.0)
                except subprocess.TimeoutExpired:
                    p.proc.kill()
                    p.proc.wait()
        for p in self.procs:
            p.thread.join(2.0)
        for f in self._files:
            f.close()
        self._files.clear()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self._unlock_nodes()
        return {p.name: p.poll() for p in self.procs}

    def __enter__(self) -> "Suite":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def overrides_from_args(args: argparse.Namespace) -> dict[str, list[str]]:
    o: dict[str, list[str]] = {spec.name: [] for spec in SPECS}
    if args.model:
        path = str(Path(args.model).expanduser().resolve())
        for spec in SPECS:
            if spec.model:
                o[spec.name].append(f"model_path:={path}")
    if args.real_time_factor is not None:
        o["sim"].append(f"real_time_factor:={float(args.real_time_factor)!r}")
    if args.category:
        o["sim"].append(f"category:={args.category}")
    if args.use_sim_time:
        for name in o:
            o[name].append("use_sim_time:=true")
    # the launch file's state_source overlay, as it applies it: after the params file (perception: the sim's
    # camera at the 15 Hz tracking needs, too)
    for node, assignments in state_source_overlay(args.state_source).items():
        o[node] += assignments
    for item in args.param or []:
        node, sep, assignment = item.partition(":")
        if not sep or node not in o or ":=" not in assignment:
            raise ValueError(f"--param {item!r}: use NODE:NAME:=VALUE with NODE one of {sorted(o)}")
        o[node].append(assignment)
    return o


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None,
                        help=f"params file (default: config/{CONFIG_NAME} of this installation)")
    parser.add_argument("--model", default=None, help="checkpoint of perception and predictor (default: config's)")
    parser.add_argument("--real-time-factor", type=float, default=None, help="sim speed; 0 = as fast as possible")
    parser.add_argument("--category", default=None, help="shape category the sim spawns at start")
    parser.add_argument("--nodes", default=None, help=f"subset to start (default: {','.join(n for n, _ in NODES)})")
    parser.add_argument("--param", action="append", metavar="NODE:NAME:=VALUE",
                        help="override one parameter of one node (repeatable)")
    parser.add_argument("--log-dir", type=Path, default=None, help="write each node's output to DIR/<node>.log")
    parser.add_argument("--log-level", default=None, choices=["debug", "info", "warn", "error", "fatal"])
    parser.add_argument("--namespace", default="", help="ROS namespace of every node and its topics, e.g. robot1")
    parser.add_argument("--use-sim-time", action="store_true", help="the nodes' time from /clock (sim:publish_clock)")
    parser.add_argument("--no-sim", action="store_true", help="do not start the sim node (feed cloud from your sensor; "
                        "initial_twist and object_state from your tracker, or use --state-source perception)")
    parser.add_argument("--state-source", choices=("sim", "perception"), default="sim", help="perception: the "
                        "predictor and the pusher read the perception node's tracked_state and initial_state, never "
                        "the sim's truth; the sim renders depth-camera clouds at 15 Hz")
    parser.add_argument("--dds-profile", type=Path, default=None, help="Fast DDS XML profile (default: the "
                        "environment's, else config/fastdds.xml)")
    parser.add_argument("--no-autostart", action="store_true", help="start the managed nodes unconfigured "
                        "(autostart:=false) for a lifecycle manager; wait until each answers get_state")
    parser.add_argument("--startup-timeout", type=float, default=180.0, help="s for every node's get_state to answer")


def run(args: argparse.Namespace) -> int:
    nodes = args.nodes.split(",") if args.nodes else [n for n, _ in NODES]
    if args.no_sim:
        nodes = [n for n in nodes if n != "sim"]
    env = None
    if args.dds_profile is not None:
        if not args.dds_profile.is_file():
            raise FileNotFoundError(f"--dds-profile {args.dds_profile} does not exist")
        env = dict(os.environ, **{var: str(args.dds_profile.resolve()) for var in DDS_PROFILE_VARS})
    suite = Suite(args.config, overrides_from_args(args), nodes, args.log_dir, args.log_level, env, args.namespace,
                  autostart=not args.no_autostart)
    stop = threading.Event()
    received: list[int] = []

    def on_signal(signum, _frame) -> None:
        received.append(signum)
        stop.set()

    # SIGHUP too (the terminal closed): every way of stopping physdyn up stops its nodes.
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        try:
            suite.start()
        except RuntimeError as exc:
            print(f"physdyn up: error: {exc}", file=sys.stderr, flush=True)
            return 1
        print(f"physdyn up: starting {', '.join(p.name for p in suite.procs)} with {suite.config}"
              f" (DDS profile: {suite.dds_profile or 'Fast DDS defaults'})", flush=True)
        try:
            try:
                ready = suite.wait_ready(args.startup_timeout, stop)
            except RuntimeError as exc:
                print(f"physdyn up: error: {exc}", file=sys.stderr, flush=True)
                return 1
            if ready and suite.autostart:
                print("physdyn up: all nodes ready, lifecycle state active (Ctrl-C to stop)", flush=True)
            elif ready:
                print("physdyn up: all nodes ready, lifecycle state unconfigured (autostart off): configure and "
                      "activate them, e.g. `ros2 lifecycle set /<node> configure` then `activate` (Ctrl-C to stop)",
                      flush=True)
            while not stop.is_set():
                d = suite.dead()
                if d is not None:
                    d.thread.join(2.0)
                    print(f"physdyn up: error: node '{d.name}' died with code {d.poll()}; stopping the others",
                          file=sys.stderr, flush=True)
                    return 1
                stop.wait(0.2)
            return 0
        finally:
            codes = suite.stop()
            if received:
                bad = {n: c for n, c in codes.items() if c not in (0, -signal.SIGINT, -signal.SIGTERM)}
                if bad:
                    print(f"physdyn up: nodes exited with {bad}", file=sys.stderr)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
