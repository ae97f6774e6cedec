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
"""Dataset format version 1 (docs/architecture.md): manifest.json + shapes.npz + shards/shard_XXXXX.npz.

numpy only (no pybullet, no torch). Every file is written atomically: a temporary name in the same folder, then
os.replace, so a reader or an interrupted writer never sees a truncated file. Archives are written with fixed
zip timestamps, so the same arrays always give the same bytes (and sha256).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np

FORMAT_NAME = "physdyn-dataset"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"
SHAPES_FILE = "shapes.npz"
SHARD_DIR = "shards"

#: Per-simulation arrays of a shard: name -> (dtype, trailing shape; "T" = num_frames).
SHARD_FIELDS: dict[str, tuple[str, tuple]] = {
    "shape_index": ("int32", ()), "scale": ("float32", (3,)), "friction": ("float32", ()),
    "mass": ("float32", ()), "inertia": ("float32", (3,)), "impulse": ("float32", (3,)),
    "impulse_point": ("float32", (3,)), "pos": ("float32", ("T", 3)), "quat": ("float32", ("T", 4)),
    "lin_vel": ("float32", ("T", 3)), "ang_vel": ("float32", ("T", 3)), "toppled": ("bool", ("T",)),
    "length": ("int32", ()), "topple_index": ("int32", ()),
    "sim_index": ("int64", ()),  # global simulation number in the dataset (reproducibility, ordering)
}


def _file_mode() -> int:
    umask = os.umask(0)  # read once at import: os.umask can only be read by setting it
    os.umask(umask)
    return 0o666 & ~umask


_FILE_MODE = _file_mode()


def shard_name(index: int) -> str:
    return f"{SHARD_DIR}/shard_{index:05d}.npz"


# ---------------------------------------------------------------------------------------------- atomic writing
# The package's one atomic writer: every file a reader may open while it is written (datasets, checkpoints, bag
# metadata, report PNGs, cached convex decompositions) goes through atomic_path / atomic_write.
@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary file in `path`'s folder (hidden name `.<name>.*.tmp`) for a writer that takes a path (e.g.
    pybullet's V-HACD): when the block ends it is fsynced and renamed onto `path`; on an exception it is deleted
    and `path` is left as it was. A reader, or an interrupted writer, never sees a truncated `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.chmod(fd, _FILE_MODE)  # mkstemp makes the file private (0600); give it the mode open() would
    os.close(fd)
    try:
        yield Path(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write(path: Path, write: Callable[[Any], Any]) -> None:
    """Write `path` through `write(binary file)` into a temporary file in the same folder, fsync, rename."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            write(fh)


def npz_bytes(arrays: Mapping[str, np.ndarray], compress: bool = True) -> bytes:
    """A .npz archive (np.load-compatible) with fixed timestamps: identical arrays -> identical bytes."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            data = io.BytesIO()
            np.lib.format.write_array(data, np.asanyarray(arrays[name]), allow_pickle=False)
            zf.writestr(info, data.getvalue())
    return buf.getvalue()


def write_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], compress: bool = True) -> str:
    """Write arrays atomically as .npz; returns the file's sha256."""
    data = npz_bytes(arrays, compress)
    atomic_write(Path(path), lambda fh: fh.write(data))
    return hashlib.sha256(data).hexdigest()


def write_json(path: str | os.PathLike, obj: Any) -> None:
    data = (json.dumps(obj, indent=1, sort_keys=False) + "\n").encode()
    atomic_write(Path(path), lambda fh: fh.write(data))


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All arrays of an .npz file (no pickles)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


# ------------------------------------------------------------------------------------------------ validation
def check_shard(arrays: Mapping[str, np.ndarray], num_frames: int, num_sims: int | None = None,
                num_shapes: int | None = None) -> int:
    """Validate a shard's arrays against the format; returns its number of simulations or raises ValueError."""
    missing = [k for k in SHARD_FIELDS if k not in arrays]
    if missing:
        raise ValueError(f"shard is missing arrays {missing}")
    n = len(arrays["shape_index"])
    for name, (dtype, trailing) in SHARD_FIELDS.items():
        a = arrays[name]
        shape = (n,) + tuple(num_frames if d == "T" else d for d in trailing)
        if a.shape != shape or a.dtype != np.dtype(dtype):
            raise ValueError(f"shard array {name} has {a.dtype}{a.shape}, expected {dtype}{shape}")
    if num_sims is not None and n != num_sims:
        raise ValueError(f"shard holds {n} simulations, expected {num_sims}")
    if num_shapes is not None and n and (arrays["shape_index"].min() < 0 or arrays["shape_index"].max() >= num_shapes):
        raise ValueError("shard shape_index out of range")
    return n


def stack_sims(sims: Iterable[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Stack per-simulation dicts (as returned by the simulator, plus shape_index / sim_index) into shard arrays."""
    sims = list(sims)
    return {name: np.stack([np.asarray(s[name]) for s in sims]).astype(dtype)
            for name, (dtype, _) in SHARD_FIELDS.items()}


# ---------------------------------------------------------------------------------------------------- reader
class Dataset:
    """Read-only view of a dataset directory (numpy only).

    `Dataset(root)` checks the manifest (format, version) and, unless `allow_partial`, that generation finished.
    `points` is the (S, 1024, 3) array of canonical clouds; `load(split)` concatenates the shards' arrays,
    keeping the simulations of that split's shapes.
    """

    def __init__(self, root: str | os.PathLike, allow_partial: bool = False) -> None:
        self.root = Path(root)
        path = self.root / MANIFEST
        if not path.is_file():
            raise FileNotFoundError(f"{self.root} is not a dataset: {MANIFEST} not found")
        try:
            self.manifest: dict = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path} is not valid JSON: {exc}") from None
        if self.manifest.get("format") != FORMAT_NAME:
            raise ValueError(f"{path}: not a {FORMAT_NAME} manifest")
        if self.manifest.get("version") != FORMAT_VERSION:
            raise ValueError(f"{path}: format version {self.manifest.get('version')} is not supported "
                             f"(this reader reads version {FORMAT_VERSION})")
        if not allow_partial and not self.manifest.get("complete", False):
            raise ValueError(f"dataset {self.root} is incomplete (generation was interrupted or is running); "
                             "rerun the same 'physdyn generate' command to finish it, or pass allow_partial=True")
        self.num_frames: int = int(self.manifest["num_frames"])
        self.dt: float = float(self.manifest["dt"])
        self.shapes: list[dict] = list(self.manifest["shapes"])
        self.splits: dict[str, list[str]] = {k: list(v) for k, v in self.manifest.get("splits", {}).items()}
        self._points: np.ndarray | None = None

    # -- shapes ----------------------------------------------------------------------------------------------
    @property
    def points(self) -> np.ndarray:
        """(S, num_points, 3) float32 canonical clouds, row = shapes[i]["index"]."""
        if self._points is None:
            self._points = load_npz(self.root / SHAPES_FILE)["points"]
        return self._points

    @property
    def shape_ids(self) -> list[str]:
        return [s["id"] for s in sorted(self.shapes, key=lambda s: s["index"])]

    def shape_indices(self, split: str | None) -> np.ndarray:
        """Rows of shapes.npz belonging to `split` (None: all)."""
        if split is None:
            return np.array(sorted(s["index"] for s in self.shapes), dtype=np.int64)
        if split not in self.splits:
            raise ValueError(f"unknown split {split!r}; this dataset has {sorted(self.splits)}")
        ids = set(self.splits[split])
        return np.array(sorted(s["index"] for s in self.shapes if s["id"] in ids), dtype=np.int64)

    # -- shards ----------------------------------------------------------------------------------------------
    @property
    def shard_entries(self) -> list[dict]:
        """Finished shards (those with a sha256) in order."""
        return [s for s in self.manifest["shards"] if s.get("sha256")]

    @property
    def num_sims(self) -> int:
        return sum(int(s["num_sims"]) for s in self.shard_entries)

    def __len__(self) -> int:
        return self.num_sims

    def iter_shards(self, verify: bool = False) -> Iterator[dict[str, np.ndarray]]:
        """Arrays of every finished shard, in order (`verify` checks each file's sha256 first)."""
        for entry in self.shard_entries:
            path = self.root / entry["file"]
            if not path.is_file():
                raise FileNotFoundError(f"dataset shard missing: {path}")
            if verify and sha256_file(path) != entry["sha256"]:
                raise ValueError(f"dataset shard {path} is corrupt (sha256 mismatch)")
            arrays = load_npz(path)
            check_shard(arrays, self.num_frames, int(entry["num_sims"]), len(self.shapes))
            yield arrays

    def load(self, split: str | None = None, fields: Iterable[str] | None = None,
             verify: bool = False) -> dict[str, np.ndarray]:
        """Concatenate the simulations (all, or those of `split`'s shapes); `fields` limits the arrays."""
        names = list(SHARD_FIELDS) if fields is None else list(fields)
        unknown = [f for f in names if f not in SHARD_FIELDS]
        if unknown:
            raise ValueError(f"unknown fields {unknown}; known: {list(SHARD_FIELDS)}")
        keep = None if split is None else self.shape_indices(split)
        parts: dict[str, list[np.ndarray]] = {n: [] for n in names}
        for arrays in self.iter_shards(verify):
            mask = slice(None) if keep is None else np.isin(arrays["shape_index"], keep)
            for n in names:
                parts[n].append(arrays[n][mask])
        out = {}
        for n in names:
            dtype, trailing = SHARD_FIELDS[n]
            empty = np.zeros((0,) + tuple(self.num_frames if d == "T" else d for d in trailing), dtype=dtype)
            out[n] = np.concatenate(parts[n]) if parts[n] else empty
        return out
