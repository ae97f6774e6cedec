"""The one way the suite's nodes run as executables: init, build, spin, clean shutdown, a clear exit code."""
from __future__ import annotations

from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None, threads: int = 0) -> int:
    """Spin the node `make_node()` until Ctrl-C / shutdown (0), on a MultiThreadedExecutor when threads > 0.

    A node that cannot start (e.g. its model cannot be loaded) logs why as `name` and returns 1.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        if threads > 0:
            executor = MultiThreadedExecutor(num_threads=threads)
            executor.add_node(node)
            executor.spin()
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - a node that cannot start says why and exits non-zero
        rclpy.logging.get_logger(name).fatal(f"cannot start: {exc}")
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
