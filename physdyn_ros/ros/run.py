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
"""The one way the suite's nodes run as executables: init, build, spin, clean shutdown, a clear exit code."""
from __future__ import annotations

import os
import signal
import threading
import time
import traceback
from typing import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.exceptions import InvalidHandle

from ..conventions import PARENT_PID_ENV

#: s between two looks at the parent pid.
PARENT_POLL = 0.5
#: s: spin_once waits this long after an entity went away during a wait.
SPIN_PAUSE = 0.01


def watch_parent(name: str, parent: int, stop: threading.Event) -> threading.Thread:
    """A daemon thread that sends this process SIGINT (the Ctrl-C path: a clean shutdown) once its parent
    process `parent` is gone, i.e. once it has been re-parented."""
    def watch() -> None:
        while not stop.wait(PARENT_POLL):
            if os.getppid() != parent:
                rclpy.logging.get_logger(name).error(
                    f"parent process {parent} (physdyn up) is gone: shutting down")
                os.kill(os.getpid(), signal.SIGINT)
                return

    thread = threading.Thread(target=watch, name="parent-watch", daemon=True)
    thread.start()
    return thread


def spin_once(executor: Executor, timeout_sec: float | None = None) -> None:
    """executor.spin_once, surviving an entity destroyed while the executor gathers its wait set.

    Deactivating a node destroys its subscriptions; when that runs on another thread than the one building the
    wait set (a MultiThreadedExecutor's worker, a test's thread), rclpy 7 still adds the subscription's QoS event
    handler to the wait set and raises InvalidHandle (ros2/rclpy#1284), which ended the spinning thread: every
    later reply of the process was lost. The entity is gone from the node by then, so the next call waits
    without it.
    """
    try:
        executor.spin_once(timeout_sec=timeout_sec)
    except InvalidHandle as exc:
        # also what a callback raises on an entity it destroyed itself: said, and a pause so that a fault that
        # persists does not spin a core
        rclpy.logging.get_logger("physdyn_spin").debug(f"an entity went away during a wait: {exc}")
        time.sleep(SPIN_PAUSE)


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None, threads: int = 0) -> int:
    """Spin the node `make_node()` until Ctrl-C / shutdown (0), on a MultiThreadedExecutor when threads > 0.

    A node that cannot start (e.g. its model cannot be loaded) logs "cannot start: <why>" as `name` and returns
    1. Once running, an exception that escapes a callback is logged with its traceback and the node spins on: no
    input stops it. With PHYSDYN_PARENT_PID set, the node stops when that process is gone.
    """
    rclpy.init(args=args)
    log = rclpy.logging.get_logger(name)
    stop = threading.Event()
    parent = os.environ.get(PARENT_PID_ENV, "").strip()
    if parent.isdigit():
        if os.getppid() != int(parent):
            log.error(f"parent process {parent} (physdyn up) is gone before the start: not starting")
            rclpy.try_shutdown()
            return 1
        watch_parent(name, int(parent), stop)
    node = None
    try:
        try:
            node = make_node()
        except (KeyboardInterrupt, ExternalShutdownException):
            return 0
        except Exception as exc:  # noqa: BLE001 - a node that cannot start says why and exits non-zero
            log.fatal(f"cannot start: {exc}")
            return 1
        executor = MultiThreadedExecutor(num_threads=threads) if threads > 0 else rclpy.get_global_executor()
        executor.add_node(node)
        while rclpy.ok():
            try:
                spin_once(executor)
            except (KeyboardInterrupt, ExternalShutdownException):
                break
            except Exception as exc:  # noqa: BLE001 - a callback's bug costs that callback, not the node
                log.error(f"a callback failed, the node goes on: {type(exc).__name__}: {exc}\n"
                          + "".join(traceback.format_exception(exc)).rstrip())
        return 0
    finally:
        stop.set()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
