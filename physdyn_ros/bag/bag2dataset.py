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
"""`physdyn bag2dataset BAG... OUT`: recorded pushes -> a dataset (format v1, docs/architecture.md).

Every push of every bag (bag/pushes.py: initial_twist or motion onset, observed states at any rate resampled to
DT = 1/15 s, rest padding and topple labels as the simulator's recorder makes them) becomes one simulation.
Each push also becomes its own *shape*: its cloud, moved into the object frame with the state at the cloud's
stamp (scale = 1, the cloud already has the object's size). Splits are therefore by push: `--test-fraction` of
the pushes are held out, which is what fine-tuning on one session and measuring on the rest of it needs.

Quantities a bag does not carry are written as NaN: mass, inertia, impulse, impulse point and (unless
--friction is given) friction. Training uses none of them.

The whole dataset is written into a temporary folder next to OUT (every file through physdyn_ros.data's
atomic writers) and renamed to OUT at the end, so OUT either does not exist or is complete.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from typing import Any
from pathlib import Path

import numpy as np

from ..conventions import DT, NUM_POINTS
from ..data.format import FORMAT_NAME, FORMAT_VERSION, check_shard, stack_sims, write_json, write_npz
from ..data.splits import make_splits
from .pushes import REST_ANG_VEL, REST_FRAMES, REST_LIN_VEL, find_pushes, load_session, object_points, push_frames

SHARD_SIZE = 256


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="+", metavar="BAG... OUT", help="one or more bags, then the dataset folder "
                                                                       "to create")
    parser.add_argument("--num-frames", type=int, default=76, help="frames per push (default 76 = 5 s, as "
                                                                    "'physdyn generate')")
    parser.add_argument("--state-topic", help="object states: ObjectState, Odometry or PoseStamped topic "
                                              "(default: object_state, else odom, else object_pose)")
    parser.add_argument("--twist-topic", default="initial_twist", help="push starts (TwistStamped); "
                                                                       "'' = detect motion onsets")
    parser.add_argument("--cloud-topic", default="cloud", help="the object's PointCloud2 (table frame)")
    parser.add_argument("--object-id", help="only states of this object_id / child_frame_id")
    parser.add_argument("--category", default="recorded", help="category name of the pushes (default recorded)")
    parser.add_argument("--friction", type=float, help="friction coefficient to store (default: unknown, NaN)")
    parser.add_argument("--test-fraction", type=float, default=0.2, help="pushes held out for test (0.2)")
    parser.add_argument("--val-fraction", type=float, default=0.1, help="of the rest, pushes for val (0.1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the splits and cloud subsampling")
    parser.add_argument("--onset-speed", type=float, default=0.05,
                        help="m/s: motion onset threshold without initial_twist (default 0.05)")
    parser.add_argument("--rest-speed", type=float, default=REST_LIN_VEL, help="m/s: at rest below (0.01)")
    parser.add_argument("--rest-spin", type=float, default=REST_ANG_VEL, help="rad/s: at rest below (0.05)")
    parser.add_argument("--rest-frames", type=int, default=REST_FRAMES,
                        help="consecutive still frames that make rest (4)")


def convert(bags: list[str | Path], out: str | Path, num_frames: int = 76, state_topic: str | None = None,
            twist_topic: str | None = "initial_twist", cloud_topic: str = "cloud", object_id: str | None = None,
            category: str = "recorded", friction: float | None = None, test_fraction: float = 0.2,
            val_fraction: float = 0.1, seed: int = 0, onset_speed: float = 0.05,
            rest_speed: float = REST_LIN_VEL, rest_spin: float = REST_ANG_VEL, rest_frames: int = REST_FRAMES,
            log=print) -> dict:
    """Write the dataset; returns its manifest. Skipped pushes are logged with their reason."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"OUT {out} exists and is not an empty folder; choose a new dataset folder")
    if num_frames < 2:
        raise ValueError(f"--num-frames must be >= 2, got {num_frames}")
    if friction is not None and not 0 <= friction <= 10:
        raise ValueError(f"--friction must be in [0, 10], got {friction}")
    if rest_frames < 1 or rest_speed <= 0 or rest_spin <= 0:
        raise ValueError("--rest-frames must be >= 1 and --rest-speed / --rest-spin positive")
    sims: list[dict[str, Any]] = []
    shapes: list[dict[str, Any]] = []
    points: list[np.ndarray] = []
    skipped: list[str] = []
    for bag in bags:
        session = load_session(bag, state_topic=state_topic, twist_topic=twist_topic or None,
                               cloud_topic=cloud_topic or None, prediction_topic=None, object_id=object_id)
        pushes = find_pushes(session, onset_speed=onset_speed, rest_frames=rest_frames)
        name = Path(bag).resolve().name
        for push in pushes:
            try:
                frames = push_frames(session, push, num_frames, rest_speed, rest_spin, rest_frames)
                pts = object_points(session, push, NUM_POINTS, seed=seed + push.index)
            except ValueError as exc:
                skipped.append(f"{name} push {push.index}: {exc}")
                continue
            row = len(shapes)
            ext = pts.max(0) - pts.min(0)
            shapes.append({"id": f"{name}/push_{push.index:04d}", "category": category, "index": row,
                           "bag": str(Path(bag).resolve()), "push": push.index, "t0_ns": int(push.t0),
                           "extents": [round(float(x), 6) for x in ext]})
            points.append(pts)
            nan3 = np.full(3, np.nan, dtype=np.float32)
            frames.update(shape_index=np.int32(row), sim_index=np.int64(row), scale=np.ones(3, np.float32),
                          friction=np.float32(np.nan if friction is None else friction), mass=np.float32(np.nan),
                          inertia=nan3, impulse=nan3, impulse_point=nan3)
            sims.append(frames)
        log(f"{name}: {len(pushes)} push(es) found on {session.states.topic} ({session.states.msgtype})")
    for s in skipped:
        log(f"skipped {s}")
    if not sims:
        raise ValueError("no usable push in " + ", ".join(str(b) for b in bags)
                         + (f" ({len(skipped)} skipped, see above)" if skipped else ""))
    splits = make_splits(shapes, seed=seed, test_fraction=test_fraction, val_fraction=val_fraction)
    parent = out.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    try:
        write_npz(tmp / "shapes.npz", {"points": np.stack(points).astype(np.float32)})
        entries = []
        for j in range(0, len(sims), SHARD_SIZE):
            arrays = stack_sims(sims[j:j + SHARD_SIZE])
            check_shard(arrays, num_frames, num_shapes=len(shapes))
            file = f"shards/shard_{j // SHARD_SIZE:05d}.npz"
            entries.append({"file": file, "num_sims": len(arrays["shape_index"]), "seed": seed,
                            "sha256": write_npz(tmp / file, arrays)})
        length = np.array([s["length"] for s in sims])
        toppled = np.array([s["topple_index"] >= 0 for s in sims])
        split_of = {i: k for k, ids in splits.items() for i in ids}
        manifest = {
            "format": FORMAT_NAME, "version": FORMAT_VERSION,
            "generator": {"source": "bag2dataset", "bags": [str(Path(b).resolve()) for b in bags],
                          "state_topic": state_topic, "twist_topic": twist_topic, "cloud_topic": cloud_topic,
                          "object_id": object_id, "friction": friction, "test_fraction": test_fraction,
                          "val_fraction": val_fraction, "rest_speed": rest_speed, "rest_spin": rest_spin,
                          "rest_frames": rest_frames, "onset_speed": onset_speed, "skipped": skipped},
            "seed": seed, "dt": DT, "num_frames": num_frames, "num_points": NUM_POINTS, "shapes": shapes,
            "splits": splits, "shards": entries,
            "counts": {"sims": len(sims), "shapes": len(shapes), "shards": len(entries),
                       "toppled": int(toppled.sum()), "toppled_fraction": round(float(toppled.mean()), 4),
                       "mean_length": round(float(length.mean()), 2),
                       "categories": {category: {"shapes": len(shapes), "sims": len(sims),
                                                 "toppled": int(toppled.sum())}},
                       "splits": {k: {"shapes": len(v), "sims": sum(1 for s in shapes if split_of[s["id"]] == k)}
                                  for k, v in splits.items()}},
            "complete": True}
        write_json(tmp / "manifest.json", manifest)
        if out.exists():
            out.rmdir()  # empty (checked above); os.rename needs the target gone or empty
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log(f"dataset {out}: {len(sims)} pushes ({', '.join(f'{k} {len(v)}' for k, v in splits.items())}), "
        f"{int(toppled.sum())} toppled, {len(skipped)} skipped")
    return manifest


def run(args: argparse.Namespace) -> int:
    if len(args.paths) < 2:
        raise ValueError("give at least one BAG and the OUT dataset folder")
    *bags, out = args.paths
    convert(bags, out, num_frames=args.num_frames, state_topic=args.state_topic, twist_topic=args.twist_topic,
            cloud_topic=args.cloud_topic, object_id=args.object_id, category=args.category,
            friction=args.friction, test_fraction=args.test_fraction, val_fraction=args.val_fraction,
            seed=args.seed, onset_speed=args.onset_speed, rest_speed=args.rest_speed, rest_spin=args.rest_spin,
            rest_frames=args.rest_frames, log=lambda s: print(s, file=sys.stdout, flush=True))
    return 0
