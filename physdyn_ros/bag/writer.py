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
"""A rosbag2 bag written as successive storage files, so a crash loses at most the file being written.

rosbags' Writer produces one storage file per bag and makes it readable only in close() (MCAP needs its
summary and footer, the bag its metadata.yaml). It does not split. This writer therefore runs one rosbags Writer
per *split*: split i is written to `<bag>/<bag>_i/<bag>_i.mcap` and, once it is finished (by duration, by size,
or at the end), closed by rosbags, moved to `<bag>/<bag>_i.mcap` and appended to `<bag>/metadata.yaml`, which
is rewritten atomically (temporary file + os.replace) after every split. This is the layout `ros2 bag record
--max-bag-duration/--max-bag-size` produces (metadata version 9, `relative_file_paths` + `files`), so
`ros2 bag info/play`, rosbags and Foxglove (file by file) read it.

Loss bounds: after a clean close nothing is lost. After kill -9 or power loss every finished split stays
readable; what the bag loses is the unfinished split: at most `split_duration` seconds of wall time (plus one
`tick()` period) or `split_size` bytes of messages, whichever bound is hit first. The unfinished split stays in
its folder `<bag>/<bag>_i/`, listed nowhere. With MCAP it is written incrementally (_IncrementalMcapWriter):
the header at once, then each chunk with its message indexes as soon as it is complete, handed to the OS at
once: a chunk is completed when its first message is `chunk_period` (CHUNK_PERIOD, 1 s) old, checked by
`tick()`, or when it holds 1 MiB. So after kill -9 the unfinished file holds every message but those of the
last `chunk_period` seconds (plus one `tick()` period) or the last 1 MiB, in complete chunks that
`mcap recover` salvages (it has no summary and no footer, so rosbags does not open it). The chunks are not
fsynced: after a power loss the unfinished file holds what the OS had written back. With sqlite3 the
unfinished split's messages are committed only when it is finished: its .db3 holds none of them.

Storage full: `open()` refuses a disk with less than `min_free` bytes free; `tick()` stops the bag cleanly
(finalizes the current split, nothing lost) once free space falls below `min_free`; a write error (ENOSPC,
EDQUOT, EFBIG, EIO) aborts the current split and deletes it to give the space back, keeping the finished ones.
`max_bytes` stops the bag cleanly before its files would exceed that many bytes. Each case raises
BagStorageError after the bag has been made consistent. No rclpy here.
"""
from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from io import StringIO
from pathlib import Path
from typing import Callable, Sequence

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.rosbag2.storage_mcap import McapWriter
from ruamel.yaml import YAML

from ..data.format import atomic_write
from .types import typestore

STORAGES: dict[str, tuple[StoragePlugin, str]] = {"mcap": (StoragePlugin.MCAP, ".mcap"),
                                                  "sqlite3": (StoragePlugin.SQLITE3, ".db3")}
METADATA = "metadata.yaml"
MiB = 1 << 20
#: Bytes a message costs in a split besides its payload (record header, index entries); used for size bounds.
MESSAGE_OVERHEAD = 64
#: Room kept for a split's summary (schemas, channels, chunk index) when checking max_bytes.
SUMMARY_RESERVE = 256 * 1024
#: How often tick() looks at the free disk space, seconds.
FREE_CHECK_PERIOD = 1.0
#: An MCAP split's open chunk is completed and handed to the OS once its first message is this old (checked by
#: tick()), or when it holds 1 MiB (rosbags' chunk size): what a kill -9 takes from the unfinished split.
CHUNK_PERIOD = 1.0
#: Bytes a completed chunk costs besides its messages (chunk record, index records, chunk index), per chunk and
#: per topic in it; added to the size estimate when tick() completes a chunk.
CHUNK_OVERHEAD, CHUNK_TOPIC_OVERHEAD = 128, 32
_EMPTY_START = 2**63 - 1  # what rosbag2 and rosbags write as the start of a bag without messages


class BagStorageError(RuntimeError):
    """Recording stopped because of the storage (disk full, size limit, write error); the bag is consistent."""


def check_output(path: str | os.PathLike) -> Path:
    """The bag folder to create; FileExistsError if it already holds a bag or anything else."""
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise FileExistsError(f"output {path} exists and is not a folder; choose a new bag folder")
        entries = list(path.iterdir())
        if (path / METADATA).exists() or any(e.suffix in (".mcap", ".db3") for e in entries):
            raise FileExistsError(f"output folder {path} already holds a bag; choose a new folder (bags are "
                                  "never overwritten or appended to)")
        if entries:
            raise FileExistsError(f"output folder {path} is not empty; choose a new or empty folder")
    return path


def parse_size(text: str | int | None) -> int | None:
    """'64M', '1.5G', '500k', '1000' (bytes) -> int; None, '0' or 'none' -> None (no limit). ValueError else."""
    if text is None or isinstance(text, int):
        return None if not text else int(text)
    s = str(text).strip().lower()
    if s in ("", "0", "none", "off"):
        return None
    mult = {"k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}
    unit = s[-1] if s[-1] in mult else ""
    s = s[:-1] if unit else s
    if s.endswith(("ib", "b")):
        raise ValueError(f"bad size {text!r}: use a number with an optional k, M, G suffix (powers of 1024)")
    try:
        value = float(s) * (mult[unit] if unit else 1)
    except ValueError:
        raise ValueError(f"bad size {text!r}: use a number with an optional k, M, G suffix (powers of 1024)") from None
    if value < 0:
        raise ValueError(f"size must not be negative, got {text!r}")
    return int(value) or None


def free_bytes(path: Path) -> int:
    """Free bytes for an unprivileged writer on the filesystem holding path (or its nearest existing parent)."""
    p = path
    while not p.exists():
        p = p.parent
    st = os.statvfs(p)
    return st.f_bavail * st.f_frsize


class _IncrementalMcapWriter(McapWriter):
    """rosbags' MCAP storage writer whose file is valid up to its last complete chunk while it is written.

    rosbags buffers the header in Python and completes a chunk only at 1 MiB, so a killed recorder left a 0-byte
    file. Here the header is handed to the OS at open and every chunk, with its message index records, as soon
    as it is complete (by size inside rosbags' write(), or by BagWriter.tick() through complete_chunk()). An
    unfinished file is then header + complete chunks (+ a partial record), what `mcap recover` salvages.
    Flushed to the OS, not fsynced: this survives kill -9; a power loss can take what the OS had not written.
    """

    def __init__(self, path: Path, compression) -> None:
        super().__init__(path, compression)
        self.bio.flush()

    def close_chunk(self) -> None:
        super().close_chunk()
        self.bio.flush()

    @property
    def chunk_topics(self) -> int:
        """Topics with messages in the open chunk (0: nothing to complete)."""
        return len(self.chunk.msgs)

    def complete_chunk(self) -> bool:
        """Write and flush the open chunk if it holds messages; whether it did."""
        if not self.chunk.msgs:
            return False
        self.close_chunk()
        return True


class _SplitWriter(Writer):
    """rosbags' bag writer with the incremental MCAP storage."""

    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: _IncrementalMcapWriter}


@dataclass
class _Topic:
    name: str
    msgtype: str
    qos: list[Qos]
    count: int = 0  # messages in finished splits


@dataclass
class _Split:
    index: int
    dir: Path
    writer: Writer
    conns: dict[int, Connection] = field(default_factory=dict)  # topic id -> rosbags Connection
    opened: float = 0.0  # clock() at open
    chunk_opened: float | None = None  # clock() at the first message of the open MCAP chunk (None: no message)
    count: int = 0
    bytes: int = 0  # payload + overhead estimate
    start_ns: int = _EMPTY_START
    end_ns: int = 0


class BagWriter:
    """Write a rosbag2 bag (metadata v9) split into files; see the module docstring for the guarantees.

    Usage: `w = BagWriter(path); w.open(); tid = w.add_topic('/x', 'pkg/msg/T', qos); w.write(tid, t_ns, data);
    w.tick()` (periodically) and `w.close()`. write/tick raise BagStorageError once the storage stops the bag.
    """

    def __init__(self, path: str | os.PathLike, *, storage: str = "mcap", split_duration: float | None = 10.0,
                 split_size: int | None = 64 * MiB, max_bytes: int | None = None, min_free: int = 64 * MiB,
                 custom_data: dict[str, str] | None = None, clock: Callable[[], float] = time.monotonic,
                 chunk_period: float = CHUNK_PERIOD) -> None:
        if storage not in STORAGES:
            raise ValueError(f"unknown storage {storage!r}; use one of {', '.join(STORAGES)}")
        if split_duration is not None and split_duration <= 0:
            raise ValueError(f"split duration must be positive, got {split_duration}")
        if split_size is not None and split_size <= 0:
            raise ValueError(f"split size must be positive, got {split_size}")
        if max_bytes is not None and max_bytes < 2 * SUMMARY_RESERVE:
            raise ValueError(f"max bytes must be at least {2 * SUMMARY_RESERVE} (room for one file's index), "
                             f"got {max_bytes}")
        if min_free < 0:
            raise ValueError(f"min free space must not be negative, got {min_free}")
        if not chunk_period > 0:
            raise ValueError(f"chunk period must be positive, got {chunk_period}")
        self.path = Path(path)
        self.name = self.path.name
        self.storage = storage
        self.plugin, self.ext = STORAGES[storage]
        self.split_duration, self.split_size = split_duration, split_size
        self.max_bytes, self.min_free = max_bytes, min_free
        self.custom_data = {"recorder": "physdyn_ros", **(custom_data or {})}
        self.clock = clock
        self.chunk_period = chunk_period
        self.topics: list[_Topic] = []
        self.files: list[dict] = []  # finished splits, rosbag2 FileInformation dicts
        self.finished_bytes = 0
        self.split: _Split | None = None
        self.next_index = 0
        self.is_open = False
        self.closed = False
        self.stopped_reason: str | None = None
        self._last_free_check = float("-inf")

    # ------------------------------------------------------------------------------------------------ state
    @property
    def message_count(self) -> int:
        """Messages in the bag so far (finished splits + the open one)."""
        return sum(t.count for t in self.topics) + (self.split.count if self.split else 0)

    @property
    def saved_count(self) -> int:
        """Messages in finished splits (what survives a crash now)."""
        return sum(t.count for t in self.topics)

    # ------------------------------------------------------------------------------------------------- open
    def open(self) -> None:
        check_output(self.path)
        parent = self.path.resolve().parent
        if not parent.is_dir():
            raise FileNotFoundError(f"cannot create bag {self.path}: folder {parent} does not exist")
        free = free_bytes(parent)
        if free < self.min_free:
            raise BagStorageError(f"not enough free space for a bag in {parent}: {free / MiB:.1f} MiB free, "
                                  f"{self.min_free / MiB:.1f} MiB required (--min-free)")
        self.path.mkdir(parents=False, exist_ok=True)
        self.is_open = True
        self._write_metadata()  # the folder is a valid (empty) bag from the start

    def add_topic(self, name: str, msgtype: str, offered_qos: Sequence[Qos] = ()) -> int:
        """Declare a topic; returns its id for write(). The type must be known to the typestore."""
        store = typestore()
        if msgtype not in store.fielddefs:
            raise ValueError(f"unknown message type {msgtype!r}")
        for t in self.topics:
            if t.name == name and t.msgtype == msgtype:
                raise ValueError(f"topic {name} ({msgtype}) was already added")
        self.topics.append(_Topic(name, msgtype, list(offered_qos)))
        tid = len(self.topics) - 1
        split = self.split
        if split is not None:
            self._guard(lambda: self._add_connection(split, tid))
        return tid

    # ------------------------------------------------------------------------------------------------ write
    def write(self, topic_id: int, timestamp_ns: int, data: bytes | memoryview) -> None:
        """Append one serialized (CDR) message received at timestamp_ns."""
        if self.closed or not self.is_open:
            raise BagStorageError(self.stopped_reason or f"bag {self.path} is not open")
        cost = len(data) + MESSAGE_OVERHEAD
        if self.max_bytes is not None:
            current = self.split.bytes if self.split else 0
            if self.finished_bytes + current + cost + SUMMARY_RESERVE > self.max_bytes:
                self._stop(f"bag size limit reached (--max-bytes {self.max_bytes} bytes)")
        if self.split is None:
            self._guard(self._open_split)
        split = self.split
        assert split is not None
        storage = split.writer.storage
        if isinstance(storage, _IncrementalMcapWriter) and not storage.chunk_topics:
            split.chunk_opened = self.clock()  # this message opens a chunk (the previous one is complete)
        self._guard(lambda: split.writer.write(split.conns[topic_id], int(timestamp_ns), data))
        split.count += 1
        split.bytes += cost
        split.start_ns = min(split.start_ns, int(timestamp_ns))
        split.end_ns = max(split.end_ns, int(timestamp_ns))
        if self.split_size is not None and split.bytes >= self.split_size:
            self._guard(self._finish_split)

    def tick(self) -> None:
        """Call periodically (e.g. every 0.1 s): finishes a split that is old enough, watches the free space."""
        if self.closed or not self.is_open:
            return
        now = self.clock()
        split = self.split
        if split is not None and self.split_duration is not None and now - split.opened >= self.split_duration:
            self._guard(self._finish_split)
        elif split is not None and split.chunk_opened is not None and now - split.chunk_opened >= self.chunk_period:
            self._guard(self._complete_chunk)
        if now - self._last_free_check >= FREE_CHECK_PERIOD:
            self._last_free_check = now
            free = free_bytes(self.path)
            if free < self.min_free:
                self._stop(f"disk almost full: {free / MiB:.1f} MiB free on the bag's filesystem, below "
                           f"--min-free {self.min_free / MiB:.1f} MiB")

    def close(self) -> None:
        """Finish the open split and the metadata. Safe to call more than once."""
        if self.closed or not self.is_open:
            self.closed = True
            return
        try:
            if self.split is not None:
                self._guard(self._finish_split)
        finally:
            self.closed = True

    # -------------------------------------------------------------------------------------------- internals
    def _guard(self, action: Callable[[], None]) -> None:
        """Run a storage action; on an OS error abort the open split (deleting it) and stop the bag."""
        try:
            action()
        except OSError as exc:
            lost = self.split.count if self.split else 0
            self._abort_split()
            self.closed = True
            self.stopped_reason = (f"cannot write bag {self.path}: {exc.strerror or exc} (errno {exc.errno}); "
                                   f"stopped, the bag keeps {self.saved_count} messages in {len(self.files)} "
                                   f"finished file(s), the last {lost} were lost")
            raise BagStorageError(self.stopped_reason) from exc

    def _stop(self, reason: str) -> None:
        """Stop cleanly: finish the open split (nothing lost), then raise BagStorageError."""
        if self.split is not None:
            self._guard(self._finish_split)
        self.closed = True
        self.stopped_reason = (f"{reason}; stopped, the bag keeps all {self.saved_count} messages received "
                               f"({len(self.files)} file(s))")
        raise BagStorageError(self.stopped_reason)

    def _split_dir(self, index: int) -> Path:
        return self.path / f"{self.name}_{index}"

    def _open_split(self) -> None:
        index = self.next_index
        self.next_index += 1
        d = self._split_dir(index)
        writer = _SplitWriter(d, version=9, storage_plugin=self.plugin)
        for k, v in self.custom_data.items():
            writer.set_custom_data(k, v)
        writer.open()
        self.split = _Split(index=index, dir=d, writer=writer, opened=self.clock())
        for tid in range(len(self.topics)):
            self._add_connection(self.split, tid)

    def _complete_chunk(self) -> None:
        """Write the open split's chunk to its file and flush it to the OS (MCAP; see _IncrementalMcapWriter)."""
        split = self.split
        assert split is not None
        storage = split.writer.storage
        assert isinstance(storage, _IncrementalMcapWriter)  # chunk_opened is only ever set for MCAP splits
        split.chunk_opened = None
        topics = storage.chunk_topics
        if storage.complete_chunk():
            split.bytes += CHUNK_OVERHEAD + CHUNK_TOPIC_OVERHEAD * topics

    def _add_connection(self, split: _Split, tid: int) -> None:
        t = self.topics[tid]
        split.conns[tid] = split.writer.add_connection(t.name, t.msgtype, typestore=typestore(),
                                                       offered_qos_profiles=t.qos)

    def _finish_split(self) -> None:
        split = self.split
        assert split is not None
        split.writer.close()  # summary + footer, and the split's own metadata.yaml (dropped below)
        src = split.dir / f"{split.dir.name}{self.ext}"
        dst = self.path / src.name
        _fsync(src)
        os.replace(src, dst)
        _fsync(self.path)
        (split.dir / METADATA).unlink(missing_ok=True)
        split.dir.rmdir()
        self.split = None
        self.files.append({"path": dst.name, "starting_time": {"nanoseconds_since_epoch": split.start_ns},
                           "duration": {"nanoseconds": max(0, split.end_ns - split.start_ns)},
                           "message_count": split.count})
        self.finished_bytes += dst.stat().st_size
        for tid, conn in split.conns.items():
            self.topics[tid].count += split.writer.counts[conn.id]
        self._write_metadata()

    def _abort_split(self) -> None:
        split, self.split = self.split, None
        if split is None:
            return
        try:
            split.writer.abort()
        except Exception:  # noqa: BLE001 - the file is being discarded anyway
            pass
        shutil.rmtree(split.dir, ignore_errors=True)  # give the space back; the finished splits stay valid

    def _write_metadata(self) -> None:
        store = typestore()
        start = min((f["starting_time"]["nanoseconds_since_epoch"] for f in self.files), default=_EMPTY_START)
        end = max((f["starting_time"]["nanoseconds_since_epoch"] + f["duration"]["nanoseconds"]
                   for f in self.files), default=0)
        count = sum(f["message_count"] for f in self.files)
        info = {
            "version": 9,
            "storage_identifier": self.storage,
            "relative_file_paths": [f["path"] for f in self.files],
            "duration": {"nanoseconds": max(0, end - start) if count else 0},
            "starting_time": {"nanoseconds_since_epoch": start if count else _EMPTY_START},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.msgtype, "serialization_format": "cdr",
                                    "offered_qos_profiles": dump_qos_v9(t.qos),
                                    "type_description_hash": store.hash_rihs01(t.msgtype)},
                 "message_count": t.count}
                for t in self.topics],
            "compression_format": "",
            "compression_mode": "",
            "files": list(self.files),
            "custom_data": dict(self.custom_data),
            "ros_distro": "rosbags",
        }
        yaml = YAML(typ="safe")
        yaml.default_flow_style = False
        text = StringIO()
        yaml.dump({"rosbag2_bagfile_information": info}, text)
        atomic_write(self.path / METADATA, lambda fh: fh.write(text.getvalue().encode("utf8")))


def _fsync(path: Path) -> None:
    """Flush a file or folder to disk (a finished split must survive a power loss, not only a kill)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
