"""Helpers shared by the test_bag_* modules (no tests here): messages, a recorder process, reading bags back."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from conftest import PYTHON, ROOT

OBJECT_STATE = "physdyn_ros/msg/ObjectState"


def object_state_bytes(i: int, frame: str = "world", object_id: str = "obj") -> bytes:
    """A distinct ObjectState (CDR, zero padding) per i, serialized by rosbags: what a raw publisher sends."""
    from physdyn_ros.bag.types import serialize, typestore

    T = typestore().types
    Vec, Pt = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Point"]
    msg = T[OBJECT_STATE](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=i // 15, nanosec=(i % 15) * 1000),
                                        frame_id=frame),
        object_id=f"{object_id}_{i}",
        pose=T["geometry_msgs/msg/Pose"](position=Pt(x=0.01 * i, y=-0.5 * i, z=0.05),
                                         orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        twist=T["geometry_msgs/msg/Twist"](linear=Vec(x=float(i), y=0.0, z=0.0), angular=Vec(x=0.0, y=0.0, z=1.0)),
        toppled=bool(i % 2), topple_probability=float(i % 7) / 7)
    return serialize(msg, OBJECT_STATE)


def string_bytes(text: str) -> bytes:
    from physdyn_ros.bag.types import serialize, typestore

    return serialize(typestore().types["std_msgs/msg/String"](data=text), "std_msgs/msg/String")


def read_bag(path: str | Path) -> list[tuple[str, int, bytes]]:
    """(topic, receive time, bytes) of every message, in the order the reader yields them."""
    from rosbags.rosbag2 import Reader

    with Reader(Path(path)) as reader:
        return [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]


class Recorder:
    """`physdyn record` in a subprocess; waits until it announces itself."""

    def __init__(self, out: Path, *args: str, timeout: float = 30.0) -> None:
        self.proc = subprocess.Popen([PYTHON, "-m", "physdyn_ros.cli", "record", "-o", str(out), *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if line.startswith("recording "):
                return
            if not line and self.proc.poll() is not None:
                raise RuntimeError(f"recorder exited ({self.proc.returncode}): {self.proc.stderr.read()[-2000:]}")
        self.kill()
        raise TimeoutError("recorder did not start")

    def stop(self, sig: int = signal.SIGINT, timeout: float = 20.0) -> tuple[int, str, str]:
        self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode, out, err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=20)


def wait_until(predicate, timeout: float = 20.0, spin=None) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        if spin is not None:
            spin()
        else:
            time.sleep(0.02)
    return False
