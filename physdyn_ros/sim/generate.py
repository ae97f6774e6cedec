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
"""`physdyn generate`: simulate random pushes with pybullet and write a dataset (format v1, docs/architecture.md).

Determinism: shapes come from (category, index, seed); shard j's seed is derived from the master seed with
numpy's SeedSequence, and simulation i of shard j draws from default_rng([shard_seed, i]) in a fresh pybullet
world. Shard bytes therefore depend only on the parameters and j, never on the worker count or scheduling.

Resumability: every file is written atomically (temporary name + os.replace) and the manifest is rewritten
after each finished shard, so an interruption (Ctrl-C, kill -9) loses at most the shards in progress. Rerunning
the same command verifies finished shards (sha256 and simulation count) and only computes the missing ones.
`--shard-range A:B` lets several machines share one dataset: each runs the same command with its own range,
then the shard files are copied together and the full command is rerun once (it adopts valid shards).

This module is the command (`add_arguments`, `run`) and `generate()`, which runs the steps in order; the steps
live in physdyn_ros.sim.generation: `params` (defaults <- YAML <- command line), `workers` (shapes, shard plan,
the simulations of a shard, the worker pool) and `manifest` (the manifest on disk, adopting finished shards).
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

from ..data.format import write_json
from .generation.manifest import (adopt_shard, dataset_counts, diff_params, fingerprint, locked, read_manifest,
                                  remove_stale_temps, test_groups)
from .generation.params import CONFIG_DIR, DEFAULTS, parse_range, resolve_params
from .generation.workers import build_shapes, compute_shards, plan_shards, shard_seed, sigterm_as_interrupt, \
    simulate_shard

__all__ = ["CONFIG_DIR", "DEFAULTS", "add_arguments", "build_shapes", "fingerprint", "generate", "parse_range",
           "plan_shards", "resolve_params", "run", "shard_seed", "simulate_shard", "test_groups"]


# ------------------------------------------------------------------------------------------------ arguments
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", metavar="OUT", help="dataset directory to create or resume")
    parser.add_argument("--config", help="YAML generator config (a path, or a name in config/, "
                                         "e.g. generate_combined); command-line options override it")
    parser.add_argument("--categories", help="comma-separated categories: box, cylinder, bottle, mug, trashcan, "
                                             "speaker, the families of physdyn_ros.shapes.FAMILIES (superellipsoid, "
                                             "ring, dumbbell, ...; docs/architecture.md), pybullet_data (test "
                                             "only), custom (--mesh)")
    parser.add_argument("--num-sims", type=int, help="total simulations (all splits)")
    parser.add_argument("--shapes-per-category", type=int, help="distinct shapes per procedural category")
    parser.add_argument("--seed", type=int, help="master seed (shapes, splits, pushes)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    parser.add_argument("--shard-size", type=int, help="simulations per shard file")
    parser.add_argument("--num-frames", type=int, help="frames per simulation (>= 61; default 76 = 5 s)")
    fr = parser.add_mutually_exclusive_group()
    fr.add_argument("--friction", type=float, help="effective friction coefficient of every simulation")
    fr.add_argument("--vary-friction", action="store_true", default=None,
                    help="draw the friction of each simulation from U(0.35, 0.65)")
    parser.add_argument("--mesh", dest="meshes", action="append", metavar="PATH",
                        help="a user mesh (OBJ/STL/PLY, metres, z up) or a folder of them, added as category "
                             "'custom'; repeat for several")
    parser.add_argument("--leave-out", help="comma-separated categories put entirely in the test split (held "
                                            "out of training; reported apart in the manifest's test_groups)")
    parser.add_argument("--test-fraction", type=float, help="fraction of each category's shapes in test")
    parser.add_argument("--collision", choices=["auto", "hull"],
                        help="auto: convex decomposition for concave shapes; hull: convex hull for all")
    parser.add_argument("--shard-range", "--seed-range", dest="shard_range", metavar="A:B",
                        help="only compute shards A..B-1 (to split one dataset across machines)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


# ------------------------------------------------------------------------------------------------------- run
def generate(out: str | os.PathLike, p: dict[str, Any], workers: int | None = None, shard_range: str | None = None,
             progress: bool = True) -> dict:
    """Generate (or resume) the dataset in `out` with resolved parameters `p`; returns the manifest."""
    out = Path(out)
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers <= 0:
        raise ValueError(f"workers must be positive, got {workers}")
    _check_out(out, p)
    # Everything that can fail on bad input happens before anything is written.
    shapes = build_shapes(p)
    plan = plan_shards(p)
    todo_range = parse_range(shard_range, len(plan))
    manifest = _new_manifest(p, shapes, plan)

    _start_writing(out, shapes)
    _adopt_finished_shards(out, manifest, p, todo_range, len(shapes))
    todo = [j for j in todo_range if not manifest["shards"][j]["sha256"]]
    concave = _concave_shapes_used(todo, manifest, p, shapes)

    def finished(j: int, digest: str, n: int) -> None:
        with locked(out):
            current = read_manifest(out) or manifest
            for mine, theirs in zip(manifest["shards"], current["shards"]):
                if theirs.get("sha256") and not mine["sha256"]:
                    mine["sha256"] = theirs["sha256"]  # finished by a process sharing this OUT
            manifest["shards"][j]["sha256"] = digest
            write_json(out / "manifest.json", manifest)

    cache_dir = None  # SimConfig's default: $PHYSDYN_CACHE/vhacd or ~/.cache/physdyn_ros/vhacd
    total = sum(manifest["shards"][j]["num_sims"] for j in todo)
    with sigterm_as_interrupt():
        compute_shards(out, shapes, p, cache_dir, todo, concave, total, workers, progress, finished)
    _finish_manifest(out, manifest)
    return manifest


def _check_out(out: Path, p: dict[str, Any]) -> None:
    """OUT must be new, empty, or hold a dataset made with exactly these parameters (then it is resumed)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"OUT {out} exists and is not a directory")
    existing = read_manifest(out) if out.is_dir() else None
    if existing is None and out.is_dir() and any(f for f in out.iterdir() if f.name != ".lock"):
        raise ValueError(f"OUT {out} is not empty and holds no dataset manifest; choose a new directory")
    if existing is not None:
        if existing.get("format") != "physdyn-dataset":
            raise ValueError(f"{out}/manifest.json is not a physdyn dataset manifest")
        if existing.get("generator") != p:
            diff = diff_params(existing.get("generator", {}), p)
            raise ValueError(f"OUT {out} holds a dataset made with other parameters ({'; '.join(diff[:4])}"
                             f"{' ...' if len(diff) > 4 else ''}); use a new directory or the same parameters")


def _new_manifest(p: dict[str, Any], shapes: list, plan: list[dict]) -> dict:
    """The manifest of the dataset (shapes, object-level splits, shard plan), not complete yet."""
    from ..conventions import DT, NUM_POINTS
    from ..data.format import FORMAT_NAME, FORMAT_VERSION
    from ..data.splits import make_splits

    entries = [{"id": s.name, "category": s.category, "index": i, "convex": s.convex,
                "extents": [round(float(x), 6) for x in s.extents],
                "volume": round(float(s.mass_properties().volume), 9), "params": s.params}
               for i, s in enumerate(shapes)]
    splits = make_splits(entries, seed=p["seed"], test_fraction=p["test_fraction"],
                         val_fraction=p["val_fraction"], leave_out=p["leave_out"])
    for s in shapes:
        s.hull()  # computed here (open3d) so worker processes never touch open3d
    return {"format": FORMAT_NAME, "version": FORMAT_VERSION, "generator": p, "seed": p["seed"], "dt": DT,
            "num_frames": p["num_frames"], "num_points": NUM_POINTS, "shapes": entries, "splits": splits,
            "test_groups": test_groups(p), "shards": plan, "counts": {}, "complete": False}


def _start_writing(out: Path, shapes: list) -> None:
    """Create OUT and its shards/ folder, drop stale temporary files, write shapes.npz (the canonical clouds)."""
    import numpy as np

    from ..data.format import write_npz

    out.mkdir(parents=True, exist_ok=True)
    (out / "shards").mkdir(exist_ok=True)
    remove_stale_temps(out)
    write_npz(out / "shapes.npz", {"points": np.stack([s.points for s in shapes]).astype(np.float32)})


def _adopt_finished_shards(out: Path, manifest: dict, p: dict[str, Any], todo_range: range,
                           num_shapes: int) -> None:
    """Verify what is on disk (recorded shards by sha256, unrecorded ones by content) and write the manifest."""
    with locked(out):
        current = read_manifest(out)
        if current is not None:
            for mine, theirs in zip(manifest["shards"], current["shards"]):
                mine["sha256"] = theirs.get("sha256")
        for j, e in enumerate(manifest["shards"]):
            if j in todo_range or e["sha256"]:
                e["sha256"] = adopt_shard(out / e["file"], e, j, p, num_shapes)
        write_json(out / "manifest.json", manifest)


def _concave_shapes_used(todo: list[int], manifest: dict, p: dict[str, Any], shapes: list) -> list[int]:
    """The concave shapes the pending shards use: their convex decompositions are computed first (in parallel),
    so that no two workers decompose the same shape at once."""
    import numpy as np

    used: set[int] = set()
    for j in todo:
        k = j * p["shard_size"] + np.arange(manifest["shards"][j]["num_sims"])
        used.update((k % len(shapes)).tolist())
    return [i for i in sorted(used) if not shapes[i].convex and p["sim"]["collision"] == "auto"]


def _finish_manifest(out: Path, manifest: dict) -> None:
    """Merge what processes sharing OUT finished; once every shard is there, the dataset is complete."""
    with locked(out):
        current = read_manifest(out) or manifest
        for mine, theirs in zip(manifest["shards"], current["shards"]):
            mine["sha256"] = mine["sha256"] or theirs.get("sha256")
        if all(e["sha256"] for e in manifest["shards"]):
            manifest["complete"] = True
            manifest["counts"] = dataset_counts(out, manifest)
        write_json(out / "manifest.json", manifest)


def run(args: argparse.Namespace) -> int:
    p = resolve_params(args)
    t = time.time()
    manifest = generate(args.out, p, workers=args.workers, shard_range=args.shard_range,
                        progress=not args.no_progress)
    done = sum(e["num_sims"] for e in manifest["shards"] if e["sha256"])
    if manifest["complete"]:
        c = manifest["counts"]
        print(f"dataset {args.out}: {c['sims']} simulations of {c['shapes']} shapes, "
              f"{c['toppled_fraction']:.0%} toppled ({time.time() - t:.0f} s)")
        for group, g in c["test_groups"].items():
            if g["shapes"]:
                print(f"  test, {group.replace('_', ' ')}: {g['shapes']} shapes, {g['sims']} simulations "
                      f"({', '.join(g['categories'])})")
    else:
        print(f"dataset {args.out}: {done}/{p['num_sims']} simulations done; run the command without "
              f"--shard-range (or with the remaining ranges) to finish it")
    return 0
