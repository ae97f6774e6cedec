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
"""Opening a bag for reading, with errors that say what is wrong with the path the user gave.

rosbags' Reader reports a .npy file as "Unrecognized storage format '.npy'", a folder without metadata.yaml as
"Expected metadata file 'x' does not exist." and a killed recording's unfinished split as "File end magic is
invalid.", in its own exception type. `open_bag` checks the path first and turns whatever rosbags refuses,
while opening or while reading messages, into a BagError (a ValueError, so `physdyn <cmd>` prints it as one
line `physdyn <cmd>: error: ...` and exits 2) naming the path and the problem.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator

from rosbags.rosbag2 import Reader, ReaderError

#: Storage files rosbags reads on their own (without a bag folder's metadata.yaml).
STORAGE_SUFFIXES = (".mcap", ".db3")
METADATA = "metadata.yaml"
_MCAP_MAGIC = b"\x89MCAP0\r\n"


class BagError(ValueError):
    """The path is not a readable rosbag2 bag; the message names the path and the problem."""


def check_bag(path: str | Path) -> Path:
    """The bag path, if it can be a bag: FileNotFoundError / BagError (one readable line) otherwise."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag {path} not found")
    if path.is_dir():
        if not (path / METADATA).is_file():
            files = sorted(p.name for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES and p.is_file())
            hint = (f"; it holds {', '.join(files[:3])}{' ...' if len(files) > 3 else ''}: pass a file to read it "
                    "alone" if files else "")
            raise BagError(f"{path} is not a rosbag2 bag (a folder with no {METADATA}){hint}")
        return path
    if path.suffix not in STORAGE_SUFFIXES:
        raise BagError(f"{path} is not a rosbag2 bag (not a folder with {METADATA}, nor an .mcap or .db3 file)")
    return path


def _explain(path: Path, exc: ReaderError) -> str:
    """rosbags' message -> one line naming the path and the problem."""
    text = " ".join(str(exc).split())
    if path.is_file() and path.suffix == ".mcap":
        head, tail = _ends(path)
        if head[:8] != _MCAP_MAGIC:
            return f"{path} is not an MCAP file (it does not start with the MCAP magic bytes)"
        if tail[-8:] != _MCAP_MAGIC:
            return (f"{path} is an unfinished or truncated MCAP file (no footer; a recording killed with kill -9 "
                    "or a power loss leaves one): salvage its complete chunks with `mcap recover`")
    if text.startswith("Could not load YAML from"):
        # "Could not load YAML from P: <problem>\n<problem>\n  in "<unicode string>", line L, column C: ..."
        lines = [ln.strip() for ln in str(exc).splitlines()]
        problem = " ".join(ln for ln in lines if ln and not ln.startswith(("in ", "^")))
        where = next((ln.split(",", 1)[1].rstrip(":").strip() for ln in lines if ln.startswith("in ")), "")
        problem = problem.split(": ", 1)[1] if ": " in problem else problem
        return f"bag {path}: {METADATA} is not valid YAML ({problem}{', ' + where if where else ''})"
    if text.startswith(("A metadata key is missing", "Invalid bag metadata")):
        return f"bag {path}: {METADATA} is not rosbag2 bag metadata ({text.rstrip('.')})"
    return f"cannot read bag {path}: {text.rstrip('.')}"


def _ends(path: Path) -> tuple[bytes, bytes]:
    with open(path, "rb") as fh:
        head = fh.read(8)
        size = fh.seek(0, 2)
        fh.seek(max(0, size - 8))
        return head, fh.read(8)


@contextlib.contextmanager
def open_bag(path: str | Path) -> Iterator[Reader]:
    """`with open_bag(p) as reader:` rosbags' Reader on a checked path; rosbags' read errors become BagError."""
    path = check_bag(path)
    try:
        with Reader(path) as reader:
            yield reader
    except ReaderError as exc:
        raise BagError(_explain(path, exc)) from exc
