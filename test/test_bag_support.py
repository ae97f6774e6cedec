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


MCAP_MAGIC = b"\x89MCAP0\r\n"


def scan_mcap(path: str | Path) -> dict:
    """Read an MCAP file record by record from its start, as `mcap recover` does, without its summary or footer.

    Independent of rosbags and of physdyn_ros' writer: a plain parser of the MCAP record layout (opcode u8,
    length u64, body). Stops at the first record that is cut short (a killed writer's last bytes). Returns
    `messages` [(topic, log_time, bytes)] from the complete chunks and from messages outside chunks, `chunks`
    (complete chunk records, each checked against its sizes and CRC), `indexed` (non-empty message index records
    after a chunk, each checked to point at that chunk's messages of its channel, with their times), `footer`
    (whether the file ends with a footer and the closing magic), `tail` (bytes after the last complete record)
    and `size`.
    """
    import struct
    import zlib

    data = Path(path).read_bytes()
    assert data[:8] == MCAP_MAGIC, f"{path}: no MCAP magic at the start ({data[:8]!r})"
    schemas: dict[int, str] = {}
    channels: dict[int, str] = {}
    messages: list[tuple[str, int, bytes]] = []
    out = {"chunks": 0, "indexed": 0, "footer": False}

    def string(buf: bytes, at: int) -> tuple[str, int]:
        (n,) = struct.unpack_from("<I", buf, at)
        return buf[at + 4:at + 4 + n].decode(), at + 4 + n

    def records(buf: bytes, at: int, end: int):
        """(opcode, body, record start) of the complete records in buf[at:end]; stops at a cut-short one."""
        while at + 9 <= end:
            op, n = buf[at], struct.unpack_from("<Q", buf, at + 1)[0]
            if at + 9 + n > end:
                return
            yield op, buf[at + 9:at + 9 + n], at
            at += 9 + n

    def handle(op: int, body: bytes) -> None:
        if op == 0x03:  # schema
            (sid,) = struct.unpack_from("<H", body, 0)
            schemas[sid], _ = string(body, 2)
        elif op == 0x04:  # channel
            cid, _sid = struct.unpack_from("<HH", body, 0)
            channels[cid], _ = string(body, 4)
        elif op == 0x05:  # message
            cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
            messages.append((channels[cid], log_time, bytes(body[22:])))

    last_end = 8
    pending_chunk: tuple[int, dict] | None = None  # (first message index, {offset in chunk: message index})
    for op, body, start in records(data, 8, len(data)):
        last_end = start + 9 + len(body)
        if op == 0x06:  # chunk: start, end, uncompressed size, crc, compression, records
            _t0, _t1, size, crc = struct.unpack_from("<QQQI", body, 0)
            compression, at = string(body, 28)
            (n,) = struct.unpack_from("<Q", body, at)
            inner = body[at + 8:at + 8 + n]
            assert compression == "" and len(inner) == size, (compression, len(inner), size)
            assert crc == 0 or zlib.crc32(inner) == crc
            first = len(messages)
            offsets = {}
            for iop, ibody, istart in records(inner, 0, len(inner)):
                if iop == 0x05:
                    offsets[istart] = len(messages)
                handle(iop, ibody)
            pending_chunk = (first, offsets)
            out["chunks"] += 1
        elif op == 0x07 and pending_chunk is not None:  # message index of the chunk just read
            cid, n = struct.unpack_from("<HI", body, 0)
            entries = [struct.unpack_from("<QQ", body, 6 + 16 * k) for k in range(n // 16)]
            first, offsets = pending_chunk
            assert all(off in offsets and messages[offsets[off]][0] == channels[cid] and
                       messages[offsets[off]][1] == t for t, off in entries), "message index does not match"
            out["indexed"] += 1 if entries else 0
        else:
            if op != 0x07:
                pending_chunk = None
            if op == 0x02:  # footer
                out["footer"] = data[last_end:] == MCAP_MAGIC
            handle(op, body)
    out.update(messages=messages, tail=len(data) - last_end, size=len(data))
    return out
