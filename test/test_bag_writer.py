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
"""The split bag writer (physdyn_ros.bag.writer) on real files: layout, metadata, size limits, write errors.

No DDS here (test_bag_record.py drives the recorder node); every bag is read back with rosbags' Reader.
"""
from __future__ import annotations

import errno
import os
import subprocess
import tempfile

import pytest
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader
from ruamel.yaml import YAML

from physdyn_ros.bag.types import SUITE_TOPICS, ensure_type, normalize_type, typestore
from physdyn_ros.bag.writer import CHUNK_PERIOD, BagStorageError, BagWriter, check_output, parse_size
from test_bag_support import OBJECT_STATE, object_state_bytes, read_bag, scan_mcap, string_bytes

INF = QosTime(9223372036, 854775807)
QOS = Qos(QosHistory.UNKNOWN, 0, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, INF, INF,
          QosLiveliness.AUTOMATIC, INF, False)


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_split_bag_reads_back_byte_for_byte(tmp_path, storage):
    clock = FakeClock()
    w = BagWriter(tmp_path / "bag", storage=storage, split_duration=1.0, split_size=30_000, clock=clock)
    w.open()
    assert (tmp_path / "bag" / "metadata.yaml").is_file()  # an empty but valid bag from the start
    a = w.add_topic("/object_state", OBJECT_STATE, [QOS])
    sent = []
    for i in range(400):
        if i == 150:  # a topic appearing mid-recording lands in the open file and the following ones
            b = w.add_topic("/chatter", "std_msgs/msg/String")
        if i >= 150 and i % 10 == 0:
            data = string_bytes(f"hello {i}")
            w.write(b, 10_000 + i, data)
            sent.append(("/chatter", 10_000 + i, data))
        data = object_state_bytes(i)
        w.write(a, 10_000 + i, data)
        sent.append(("/object_state", 10_000 + i, data))
        clock.t += 0.004 if i < 300 else 0.05  # the last messages arrive slowly: files split by duration
        w.tick()
    w.close()
    ext = ".mcap" if storage == "mcap" else ".db3"
    files = sorted(p.name for p in (tmp_path / "bag").iterdir())
    assert "metadata.yaml" in files and len(files) > 4, files
    assert all(f == "metadata.yaml" or (f.startswith("bag_") and f.endswith(ext)) for f in files)
    got = read_bag(tmp_path / "bag")
    assert sorted(got) == sorted(sent)  # every message, byte for byte, with its timestamp
    meta = YAML(typ="safe").load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == storage
    assert meta["message_count"] == len(sent) == sum(f["message_count"] for f in meta["files"])
    assert meta["relative_file_paths"] == [f["path"] for f in meta["files"]]
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert topics["/object_state"]["message_count"] == 400
    tm = topics["/object_state"]["topic_metadata"]
    assert tm["type"] == OBJECT_STATE and tm["serialization_format"] == "cdr"
    assert tm["type_description_hash"] == typestore().hash_rihs01(OBJECT_STATE)
    assert tm["offered_qos_profiles"][0]["durability"] == "transient_local"
    assert tm["offered_qos_profiles"][0]["deadline"] == {"sec": 9223372036, "nsec": 854775807}
    with Reader(tmp_path / "bag") as r:  # the definitions travel with the data (what Foxglove decodes with)
        defs = {c.topic: c.msgdef.data for c in r.connections}
        assert "MSG: geometry_msgs/Pose" in defs["/object_state"] and "float32 topple_probability" in defs[
            "/object_state"]
        assert r.duration == 400  # 10_000 .. 10_399 (rosbags reports end - start + 1)


def test_unfinished_split_is_on_disk_up_to_its_last_complete_chunk(tmp_path):
    """What kill -9 finds: header and every chunk completed by age (tick) or size are in the file, in order."""
    clock = FakeClock()
    w = BagWriter(tmp_path / "bag", split_duration=None, split_size=None, clock=clock)
    w.open()
    a = w.add_topic("/object_state", OBJECT_STATE)
    f = tmp_path / "bag" / "bag_0" / "bag_0.mcap"
    sent = []

    def on_disk():  # what another process reads now (a killed writer's Python buffers are gone)
        scan = scan_mcap(f)
        got = [(t, s, d) for t, s, d in scan["messages"]]
        assert not scan["footer"] and scan["tail"] == 0 and got == sent[:len(got)]
        return len(got), scan

    w.write(a, 1, object_state_bytes(0))
    sent.append(("/object_state", 1, object_state_bytes(0)))
    assert f.stat().st_size > 8 and on_disk()[0] == 0  # header at once, the open chunk not yet
    for i in range(1, 250):
        if i == 100:  # a topic added mid-split: its channel goes into the next chunk
            b = w.add_topic("/chatter", "std_msgs/msg/String")
        if i >= 100 and i % 10 == 0:
            w.write(b, 1 + i, string_bytes(f"chat{i:03d}"))
            sent.append(("/chatter", 1 + i, string_bytes(f"chat{i:03d}")))
        w.write(a, 1 + i, object_state_bytes(i))
        sent.append(("/object_state", 1 + i, object_state_bytes(i)))
        clock.t += 0.01
        w.tick()
        # Loss bound: only messages of the last CHUNK_PERIOD (+ one tick) are not on disk yet.
        n, _ = on_disk()
        assert n >= len(sent) - (CHUNK_PERIOD / 0.01 + 1) * 1.1 - 1
    n, scan = on_disk()
    assert scan["chunks"] >= 2 and scan["indexed"] >= scan["chunks"] and n < len(sent)
    clock.t += CHUNK_PERIOD  # a quiet second: the open chunk goes out at the next tick ...
    w.tick()
    assert on_disk()[0] == len(sent)
    w.tick()  # ... and an empty one is never written
    assert on_disk()[1]["chunks"] == scan["chunks"] + 1
    big = string_bytes("x" * 300_003)
    for i in range(4):  # > 1 MiB without a tick: chunks completed by size are on disk too
        w.write(b, 1000 + i, big)
        sent.append(("/chatter", 1000 + i, big))
    assert on_disk()[0] == len(sent)
    w.close()
    assert read_bag(tmp_path / "bag") == sorted(sent, key=lambda m: m[1]) and not f.parent.exists()


def test_refusals(tmp_path):
    (tmp_path / "old").mkdir()
    w = BagWriter(tmp_path / "old" / "bag")
    w.open()
    w.close()
    with pytest.raises(FileExistsError, match="already holds a bag"):
        BagWriter(tmp_path / "old" / "bag").open()
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("x")
    with pytest.raises(FileExistsError, match="not empty"):
        check_output(tmp_path / "busy")
    (tmp_path / "empty").mkdir()
    check_output(tmp_path / "empty")  # an empty folder is fine
    with pytest.raises(ValueError, match="unknown message type 'foo_msgs/msg/Bar'"):
        ensure_type("foo_msgs/msg/Bar")
    with pytest.raises(ValueError, match="bad message type"):
        normalize_type("not a type")
    assert normalize_type("geometry_msgs/PoseStamped") == "geometry_msgs/msg/PoseStamped"
    with pytest.raises(ValueError, match="bad size"):
        parse_size("12 parsecs")
    assert parse_size("1.5M") == 3 * 2**19 and parse_size("0") is None
    with pytest.raises(BagStorageError, match="not enough free space"):
        BagWriter(tmp_path / "new", min_free=2**62).open()
    assert not (tmp_path / "new").exists()
    for msgtype in SUITE_TOPICS.values():  # every suite topic can be described in a bag
        assert msgtype in typestore().fielddefs


def test_max_bytes_stops_cleanly_and_keeps_everything(tmp_path):
    w = BagWriter(tmp_path / "bag", split_size=200_000, max_bytes=1_000_000)
    w.open()
    tid = w.add_topic("/object_state", OBJECT_STATE)
    sent = []
    with pytest.raises(BagStorageError, match="size limit reached"):
        for i in range(100_000):
            data = object_state_bytes(i)
            w.write(tid, i, data)
            sent.append(data)
    assert w.closed
    with pytest.raises(BagStorageError):
        w.write(tid, 0, sent[0])  # stays stopped
    size = sum(p.stat().st_size for p in (tmp_path / "bag").iterdir())
    assert size <= 1_000_000
    got = [d for _, _, d in read_bag(tmp_path / "bag")]
    assert got == sent  # nothing accepted was lost


def test_write_error_keeps_finished_files(tmp_path, monkeypatch):
    """A disk that fills up mid-file: the open file is dropped (space back), the finished ones stay valid."""
    w = BagWriter(tmp_path / "bag", split_size=20_000)
    w.open()
    tid = w.add_topic("/object_state", OBJECT_STATE)
    sent = []
    for i in range(250):
        data = object_state_bytes(i)
        w.write(tid, i, data)
        sent.append(data)
    saved = w.saved_count
    assert 0 < saved < 250 and w.split is not None

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(w.split.writer, "write", full)
    with pytest.raises(BagStorageError, match="No space left on device"):
        w.write(tid, 999, object_state_bytes(999))
    assert [d for _, _, d in read_bag(tmp_path / "bag")] == sent[:saved]
    assert sorted(p.name for p in (tmp_path / "bag").iterdir() if p.is_dir()) == []  # partial file removed


def _can_mount_tmpfs() -> bool:
    if os.geteuid() != 0:
        return False
    with tempfile.TemporaryDirectory() as d:
        ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", d], capture_output=True).returncode == 0
        if ok:
            subprocess.run(["umount", d], check=True)
        return ok


@pytest.mark.skipif(not _can_mount_tmpfs(), reason="needs root and tmpfs mounts for a real full filesystem")
def test_real_full_filesystem(tmp_path):
    """A 1 MiB tmpfs: the kernel's ENOSPC stops the bag; what was finished stays readable."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], check=True)
    try:
        with pytest.raises(BagStorageError, match="not enough free space"):
            BagWriter(mnt / "refused").open()  # default --min-free 64 MiB
        w = BagWriter(mnt / "bag", split_size=100_000, min_free=0)
        w.open()
        tid = w.add_topic("/object_state", OBJECT_STATE)
        sent = []
        with pytest.raises(BagStorageError, match="No space left on device"):
            for i in range(100_000):
                data = object_state_bytes(i)
                w.write(tid, i, data)
                sent.append(data)
        got = [d for _, _, d in read_bag(mnt / "bag")]
        assert len(got) == w.saved_count > 1000 and got == sent[:len(got)]
    finally:
        subprocess.run(["umount", str(mnt)], check=True)
