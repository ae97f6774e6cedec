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
"""Training windows and evaluation sequences from a dataset directory (format v1, docs/architecture.md).

Everything is vectorised over the batch in numpy (no Python loop per window or per step): a batch of 256
windows of 15 frames with 1024-point clouds takes a few milliseconds, so 2 CPU threads stay on the model.

A window of T frames starting at frame s gives the network
    cloud    (P, 3)  the object's points posed by its orientation at frame s (world-aligned axes), centred at
                     their centroid and rotated into frame C (learn/frames.py)
    vel, angvel (T, 3) states in C;  d_vel, d_angvel, d_pos, d_rot (T-1, 3) increments in C
    topple (T-1,)    label of the frame after each step (the paper's y_t = toppled[t+1]).
    com (3,)         the centre of mass relative to the cloud's centroid, in C (what a partial view hides)
With `partial` > 0 that fraction of the windows sees the object as one depth camera would (learn/views.py: the
visible side from a random viewpoint above the table, `noise` m of Gaussian sensor noise) instead of its whole
surface: the centroid, heading and shape feature then come from the visible points only, as in deployment.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np
import torch

from . import frames, views

_FIELDS = ("shape_index", "scale", "friction", "length", "topple_index", "pos", "quat", "lin_vel", "ang_vel",
           "toppled")


@dataclass
class SimArrays:
    """The simulations of one split (or several), as flat arrays indexed by simulation."""

    root: Path
    manifest: dict[str, Any]
    points: np.ndarray  # (S, Np, 3) float32 canonical shape clouds (object frame, at the COM)
    shape_index: np.ndarray  # (n,) int, row in points
    scale: np.ndarray  # (n, 3)
    friction: np.ndarray  # (n,)
    pos: np.ndarray  # (n, T, 3) world
    quat: np.ndarray  # (n, T, 4) xyzw
    lin_vel: np.ndarray  # (n, T, 3) world
    ang_vel: np.ndarray  # (n, T, 3) world
    toppled: np.ndarray  # (n, T) bool
    length: np.ndarray  # (n,) frames before rest
    topple_index: np.ndarray  # (n,) first toppled frame or -1
    category: np.ndarray  # (n,) str
    shape_id: np.ndarray  # (n,) str
    dt: float = 1.0 / 15.0
    splits: tuple[str, ...] = field(default_factory=tuple)

    def __len__(self) -> int:
        return int(self.shape_index.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.pos.shape[1])

    def subset(self, index: Sequence[int] | np.ndarray) -> "SimArrays":
        """The simulations `index` (shapes and manifest shared)."""
        index = np.asarray(index, dtype=np.int64)
        per_sim = {k: getattr(self, k)[index] for k in ("shape_index", "scale", "friction", "pos", "quat", "lin_vel",
                                                         "ang_vel", "toppled", "length", "topple_index", "category",
                                                         "shape_id")}
        return SimArrays(root=self.root, manifest=self.manifest, points=self.points, dt=self.dt, splits=self.splits,
                         **per_sim)


def dataset_identity(root: str | Path, manifest: dict[str, Any]) -> dict[str, Any]:
    """What a checkpoint records about its training data: the manifest itself plus its hash."""
    blob = json.dumps(manifest, sort_keys=True).encode()
    return {"path": str(Path(root).resolve()), "manifest_sha256": hashlib.sha256(blob).hexdigest(),
            "manifest": manifest}


def load_sims(root: str | Path, splits: Sequence[str] = ("train",), categories: Optional[Iterable[str]] = None,
              exclude_categories: Optional[Iterable[str]] = None) -> SimArrays:
    """Load the simulations whose shape belongs to `splits`, optionally filtered by category.

    Reads through physdyn_ros.data.Dataset (format and completeness checks, clear errors).
    """
    from ..data import Dataset

    ds = Dataset(root)
    by_row = {int(s["index"]): s for s in ds.shapes}
    all_cats = {s.get("category", "") for s in ds.shapes}
    keep_cat = set(categories) if categories else None
    drop_cat = set(exclude_categories or ())
    unknown = ((keep_cat or set()) | drop_cat) - all_cats
    if unknown:
        raise ValueError(f"{root}: unknown categories {sorted(unknown)} (the dataset has {sorted(all_cats)})")
    parts = [ds.load(split, fields=_FIELDS) for split in splits]
    cat = {k: np.concatenate([p[k] for p in parts]) for k in _FIELDS}
    rows = cat["shape_index"].astype(np.int64)
    category = np.array([by_row[int(r)].get("category", "") for r in rows], dtype=str)
    sel = np.ones(len(rows), dtype=bool) if keep_cat is None else np.isin(category, sorted(keep_cat))
    sel &= ~np.isin(category, sorted(drop_cat))
    if not sel.any():
        raise ValueError(f"{root}: no simulations in splits {list(splits)} with the requested categories")
    cat = {k: v[sel] for k, v in cat.items()}
    rows = rows[sel]
    return SimArrays(
        root=Path(root), manifest=ds.manifest, points=np.asarray(ds.points, dtype=np.float32), shape_index=rows,
        scale=cat["scale"].astype(np.float32), friction=cat["friction"].astype(np.float32),
        pos=cat["pos"].astype(np.float32), quat=cat["quat"].astype(np.float32),
        lin_vel=cat["lin_vel"].astype(np.float32), ang_vel=cat["ang_vel"].astype(np.float32),
        toppled=cat["toppled"].astype(bool), length=cat["length"].astype(np.int64),
        topple_index=cat["topple_index"].astype(np.int64), category=category[sel],
        shape_id=np.array([by_row[int(r)]["id"] for r in rows], dtype=str), dt=ds.dt, splits=tuple(splits))


def compute_stats(sims: SimArrays, max_sims: int = 20000) -> dict[str, float]:
    """Normalisation scales from (training!) simulations: RMS norms over the frames in motion.

    One scalar per vector quantity (see model.STAT_KEYS). Frames after rest are excluded so the scales
    describe motion, not padding. Uses at most `max_sims` simulations (a fixed, seed-free choice).
    """
    n = len(sims)
    idx = np.arange(n) if n <= max_sims else np.linspace(0, n - 1, max_sims).astype(np.int64)
    t = np.arange(sims.num_frames)
    moving = t[None, :] < sims.length[idx, None]  # (m, T)
    moving_step = moving[:, :-1]
    inc = frames.world_increments(sims.pos[idx], sims.quat[idx], sims.lin_vel[idx], sims.ang_vel[idx])

    def rms(x: np.ndarray, mask: np.ndarray) -> float:
        sq = np.sum(np.asarray(x, dtype=np.float64) ** 2, axis=-1)[mask]
        return float(np.sqrt(sq.mean())) if sq.size else 0.0

    stats = {"vel": rms(sims.lin_vel[idx], moving), "angvel": rms(sims.ang_vel[idx], moving),
             "d_vel": rms(inc["d_vel"], moving_step), "d_angvel": rms(inc["d_angvel"], moving_step),
             "d_pos": rms(inc["d_pos"], moving_step), "d_rot": rms(inc["d_rot"], moving_step)}
    pts = sims.points[sims.shape_index[idx]] * sims.scale[idx][:, None, :]
    radius = np.linalg.norm(pts - pts.mean(axis=1, keepdims=True), axis=-1).max(axis=1)
    stats["cloud"] = float(radius.mean())
    # a dataset without motion would give 0: keep the scales usable (training on it is pointless anyway)
    return {k: max(v, 1e-6) for k, v in stats.items()}


def _subsample_index(batch: int, available: int, wanted: int, rng: Optional[np.random.Generator]) -> np.ndarray:
    """(batch, wanted) point indices: a random subset per window (training) or one fixed subset (evaluation)."""
    gen = rng if rng is not None else np.random.default_rng(0)
    if wanted <= available:
        if rng is None:
            return np.broadcast_to(np.sort(gen.permutation(available)[:wanted]), (batch, wanted))
        return np.argsort(gen.random((batch, available)), axis=1)[:, :wanted]
    # fewer points than the model takes: repeat some (max-pooling is unchanged by duplicates)
    extra = gen.integers(0, available, size=(1 if rng is None else batch, wanted - available))
    base = np.broadcast_to(np.arange(available), (extra.shape[0], available))
    return np.broadcast_to(np.concatenate([base, extra], axis=1), (batch, wanted))


def partial_clouds(cloud: np.ndarray, partial: float, noise: float, rng: np.random.Generator) -> np.ndarray:
    """Replace a random `partial` fraction of the clouds (B, N, 3) (world axes, at the centre of mass) by their
    visible side from a random camera (resampled to N points) plus Gaussian noise of `noise` m."""
    cloud = np.array(cloud, dtype=np.float64)
    rows = np.flatnonzero(rng.random(len(cloud)) < partial)
    if len(rows):
        part = cloud[rows]
        mask = views.visible(part, views.random_view_dirs(len(rows), rng))
        idx = views.sample_visible(mask, part.shape[1], rng)
        part = np.take_along_axis(part, idx[..., None], axis=1)
        cloud[rows] = part + rng.normal(0.0, noise, part.shape) if noise > 0 else part
    return cloud


def above_table(cloud: np.ndarray, table: np.ndarray, gap: float) -> np.ndarray:
    """The clouds (B, N, 3) as the perception node delivers them: the points within `gap` m of the table plane
    (height table (B,), same frame) removed, the rest resampled to N (cycling; a cloud with no point above the
    gap is kept whole)."""
    keep = cloud[..., 2] > np.asarray(table, dtype=np.float64)[:, None] + gap
    keep[~keep.any(axis=1)] = True
    idx = views.sample_visible(keep, cloud.shape[1], np.random.default_rng(0))
    return np.take_along_axis(cloud, idx[..., None], axis=1)


def make_windows(sims: SimArrays, index: np.ndarray, starts: np.ndarray, length: int, num_points: int,
                 rng: Optional[np.random.Generator] = None, partial: float = 0.0, noise: float = 0.0,
                 view_rng: Optional[np.random.Generator] = None, plane_gap: float = 0.0,
                 desc_points: int = 0) -> dict[str, torch.Tensor]:
    """Windows of `length` frames of simulations `index` starting at `starts`, in frame C, as float32 tensors.

    rng: a generator for random point subsets (training); None gives the fixed subset (evaluation).
    partial / noise: the fraction of windows seen as partial views and their sensor noise (m); their views
    come from view_rng (default: rng, else a fixed seed, so evaluation is reproducible). plane_gap > 0: the
    points within that many m of the table removed, as the perception node removes the table plane (above_table).
    Extra keys: heading (B,), centroid (B, 3) of the frame placement, start (B,), sim (B,), table (B,) the height
    of the table plane (world z = 0) in frame C; with desc_points > 0, desc_cloud (B, desc_points, 3): a fixed
    subset of that many points of the same cloud in the same frame C (the topple head's descriptors, support.py).
    """
    index = np.asarray(index, dtype=np.int64)
    starts = np.asarray(starts, dtype=np.int64)
    if np.any(starts < 0) or np.any(starts + length > sims.num_frames):
        raise ValueError(f"windows of {length} frames must lie within the {sims.num_frames} stored frames")
    t = starts[:, None] + np.arange(length)[None, :]
    pick = (index[:, None], t)
    pos, quat = sims.pos[pick], sims.quat[pick]
    vel, angvel = sims.lin_vel[pick], sims.ang_vel[pick]
    cloud_world = frames.pose_cloud(sims.points[sims.shape_index[index]], sims.scale[index], quat[:, 0])
    if partial > 0:
        gen = view_rng if view_rng is not None else rng if rng is not None else np.random.default_rng(0)
        cloud_world = partial_clouds(cloud_world, partial, noise, gen)
    if plane_gap > 0:  # the posed cloud is centred at the centre of mass: the table lies at -pos_z
        cloud_world = above_table(cloud_world, -pos[:, 0, 2], plane_gap)
    sub = _subsample_index(len(index), cloud_world.shape[1], num_points, rng)
    # the frame comes from all the points; with desc_points both subsets are taken from one placement
    canon = frames.canonicalize_cloud(cloud_world, keep=None if desc_points > 0 else sub)
    cloud = canon.points
    if desc_points > 0:
        dense = _subsample_index(len(index), cloud_world.shape[1], desc_points, None)
        desc_cloud = np.take_along_axis(cloud, dense[..., None], axis=-2)
        cloud = np.take_along_axis(cloud, sub[..., None], axis=-2)
    heading = np.asarray(canon.heading).reshape(len(index))
    h = heading[:, None]
    inc = frames.world_increments(pos, quat, vel, angvel)
    # the posed cloud is centred at the centre of mass: the COM seen from the centroid is -centroid
    out = {"cloud": cloud, "vel": frames.world_to_c(vel, h), "angvel": frames.world_to_c(angvel, h),
           "topple": sims.toppled[pick][:, 1:].astype(np.float32), "com": frames.world_to_c(-canon.centroid, heading),
           "table": -(pos[:, 0, 2] + canon.centroid[:, 2])}
    if desc_points > 0:
        out["desc_cloud"] = desc_cloud
    for k, v in inc.items():
        out[k] = frames.world_to_c(v, h)
    tensors = {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in out.items()}
    tensors["heading"] = torch.from_numpy(heading)
    tensors["centroid"] = torch.from_numpy(canon.centroid)
    tensors["start"] = torch.from_numpy(starts)
    tensors["sim"] = torch.from_numpy(index)
    return tensors


def random_starts(sims: SimArrays, index: np.ndarray, window: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform window starts while the object still moves: s in [0, min(length - 1, T - window)].

    The original's simulations ended at rest; ours are padded with the rest pose, so starting windows in the
    padding would train mostly on "nothing happens".
    """
    if sims.num_frames < window:
        raise ValueError(f"the dataset has {sims.num_frames} frames per simulation; windows need {window}")
    hi = np.minimum(np.maximum(sims.length[index] - 1, 0), sims.num_frames - window)
    return (rng.random(len(index)) * (hi + 1)).astype(np.int64)


def fixed_windows(sims: SimArrays, window: int, per_sim: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A fixed set of validation windows (same every evaluation, independent of the training seed)."""
    rng = np.random.default_rng(seed)
    index = np.repeat(np.arange(len(sims)), per_sim)
    return index, random_starts(sims, index, window, rng)


class WindowDataset(torch.utils.data.Dataset):
    """Random `window`-frame windows, one per simulation per epoch (the paper's epoch).

    __getitems__ (used by DataLoader for whole batches) and `batch` are vectorised. Training uses `batch`
    with a generator derived from (seed, epoch, batch index, rank), which makes every batch reproducible
    without state and a resumed run continue exactly (learn/loop.py).
    """

    def __init__(self, sims: SimArrays, window: int = 15, num_points: int = 1024, seed: int = 0,
                 partial: float = 0.0, noise: float = 0.0) -> None:
        if not 0.0 <= partial <= 1.0 or noise < 0:
            raise ValueError(f"partial must be in [0, 1] and noise >= 0, got {partial}, {noise}")
        self.partial, self.noise = float(partial), float(noise)
        if window < 2:
            raise ValueError("window must be >= 2 frames")
        if sims.num_frames < window:
            raise ValueError(f"the dataset has {sims.num_frames} frames per simulation; windows need {window}")
        self.sims, self.window, self.num_points = sims, window, num_points
        self._rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return len(self.sims)

    def batch(self, index: Sequence[int] | np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        index = np.asarray(index, dtype=np.int64)
        starts = random_starts(self.sims, index, self.window, rng)
        return make_windows(self.sims, index, starts, self.window, self.num_points, rng, self.partial, self.noise)

    def __getitems__(self, indices: list[int]) -> dict[str, torch.Tensor]:
        return self.batch(indices, self._rng)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {k: v[0] for k, v in self.batch([int(i)], self._rng).items()}


def sequences(sims: SimArrays, horizon: int, num_points: int, index: Optional[np.ndarray] = None,
              partial: float = 0.0, noise: float = 0.0, view_seed: int = 0,
              plane_gap: float = 0.0, desc_points: int = 0) -> dict[str, torch.Tensor]:
    """Whole evaluation sequences: frames 0..horizon of each simulation, the cloud posed at frame 0
    (partial > 0: that fraction seen as partial views, reproducible by view_seed; plane_gap, desc_points:
    make_windows)."""
    if horizon + 1 > sims.num_frames:
        raise ValueError(f"horizon {horizon} needs {horizon + 1} frames; the dataset stores {sims.num_frames}")
    index = np.arange(len(sims)) if index is None else np.asarray(index, dtype=np.int64)
    return make_windows(sims, index, np.zeros(len(index), dtype=np.int64), horizon + 1, num_points, None,
                        partial, noise, np.random.default_rng(view_seed), plane_gap, desc_points)
