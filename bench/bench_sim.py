#!/usr/bin/env python3
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
"""Simulation throughput per category on this machine, and the time a full dataset would take.

    nice .venv/bin/python bench/bench_sim.py --workers 2 --sims 60

Prints simulations/s per category with N worker processes (the generator's pool), the topple fraction and the
initial speed ranges, the V-HACD time per concave shape (one-off, cached), and extrapolates to the paper's
65,715 simulations and to a 50k Combined set (equal simulations per category).
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from physdyn_ros.shapes import CATEGORIES, generate_shapes  # noqa: E402
from physdyn_ros.sim import PushConfig, SimConfig, Simulator, convex_decomposition, simulate_push  # noqa: E402

_SHAPES: dict = {}
_CFG: dict = {}


def _work(task: tuple[str, int, int]) -> list[tuple[float, float, float, bool, int]]:
    category, start, count = task
    if "sim" not in _CFG:
        _CFG["sim"] = Simulator(_CFG["config"])
    shapes = _SHAPES[category]
    rows = []
    for i in range(start, start + count):
        out = simulate_push(_CFG["sim"], shapes[i % len(shapes)], np.random.default_rng([7, i]), PushConfig(),
                            num_frames=76)
        rows.append((float(np.linalg.norm(out["lin_vel"][0])), float(np.linalg.norm(out["ang_vel"][0])),
                     float(np.abs(out["ang_vel"]).max()), bool(out["topple_index"] >= 0), int(out["length"])))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--sims", type=int, default=60, help="simulations per category")
    ap.add_argument("--shapes", type=int, default=12, help="shapes per category")
    ap.add_argument("--categories", default=",".join(CATEGORIES))
    ap.add_argument("--collision", choices=["auto", "hull"], default="auto")
    args = ap.parse_args()
    cats = [c for c in args.categories.split(",") if c]
    with tempfile.TemporaryDirectory(prefix="physdyn_bench_vhacd_") as cache:  # cold cache: times V-HACD too
        return _bench(args, cats, SimConfig(collision=args.collision, vhacd_cache_dir=cache))


def _bench(args: argparse.Namespace, cats: list[str], config: SimConfig) -> int:
    _CFG["config"] = config
    for c in cats:
        _SHAPES[c] = generate_shapes(c, args.shapes, seed=0)
        for s in _SHAPES[c]:
            s.hull()
    vhacd = []
    if args.collision == "auto":
        for c in cats:
            for s in _SHAPES[c]:
                if not s.convex:
                    t = time.perf_counter()
                    convex_decomposition(s, config)
                    vhacd.append(time.perf_counter() - t)
    chunk = max(1, args.sims // (4 * args.workers))
    rates = {}
    print(f"{args.workers} worker(s), {args.sims} simulations x {len(cats)} categories, collision={args.collision}, "
          f"76 frames, physics {config.physics_hz} Hz")
    print(f"{'category':10s} {'sims/s':>7s} {'topple':>7s} {'len':>5s} {'v0 max':>7s} {'v0 med':>7s} "
          f"{'w0 max':>7s} {'w max':>7s}")
    with mp.get_context("fork").Pool(args.workers) as pool:
        pool.map(_work, [(cats[0], 0, 1)] * args.workers)  # warm up: imports, pybullet clients
        for c in cats:
            tasks = [(c, s, min(chunk, args.sims - s)) for s in range(0, args.sims, chunk)]
            t = time.perf_counter()
            rows = [r for part in pool.map(_work, tasks, chunksize=1) for r in part]
            dt = time.perf_counter() - t
            a = np.array(rows)
            rates[c] = len(rows) / dt
            print(f"{c:10s} {rates[c]:7.1f} {a[:, 3].mean():7.2f} {a[:, 4].mean():5.1f} {a[:, 0].max():7.2f} "
                  f"{np.median(a[:, 0]):7.2f} {a[:, 1].max():7.1f} {a[:, 2].max():7.1f}", flush=True)
    mix = len(cats) / sum(1 / rates[c] for c in cats)  # equal simulations per category
    print(f"mixed rate (equal sims per category): {mix:.1f} sims/s")
    for n, name in ((65_715, "paper scale (65,715 sims)"), (50_000, "Combined 50k")):
        print(f"{name}: {n / mix / 3600:.2f} h with {args.workers} worker(s)")
    if vhacd:
        v = np.array(vhacd)
        print(f"V-HACD (res {config.vhacd_resolution}): {v.mean():.2f} s mean, {v.max():.2f} s max per concave shape "
              f"({len(v)} shapes; cached on disk, one-off per shape)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
