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
"""The simulation side of `physdyn generate`: which shapes and shards a dataset has, the simulations of one
shard (a pure function of the parameters and the shard index), and the worker pool that computes the pending
shards (fork; the parent handles Ctrl-C / SIGTERM, workers die with it) after the convex decompositions they need.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator


def build_shapes(p: dict[str, Any]) -> list:
    """All shapes of the dataset, in manifest order."""
    from ...shapes import PYBULLET_DATA_CATEGORY, generate_shapes, load_mesh, pybullet_data_shapes

    shapes = []
    for cat in p["categories"]:
        if cat == PYBULLET_DATA_CATEGORY:
            got = pybullet_data_shapes(p["shapes_per_category"], p["pybullet_data_max_random"])
            if not got:
                raise ValueError("no usable pybullet_data meshes found")
            shapes += got
        elif cat == "custom":
            for i, path in enumerate(p["meshes"]):
                shapes.append(load_mesh(path, name=f"custom_{i:04d}_{Path(path).stem}", category="custom"))
        else:
            shapes += generate_shapes(cat, p["shapes_per_category"], p["seed"])
    names = [s.name for s in shapes]
    if len(set(names)) != len(names):
        raise ValueError("shape names are not unique")
    return shapes


def shard_seed(seed: int, index: int) -> int:
    import numpy as np

    return int(np.random.SeedSequence(entropy=seed, spawn_key=(2, index)).generate_state(1, np.uint64)[0] >> 1)


def plan_shards(p: dict[str, Any]) -> list[dict]:
    n, size = p["num_sims"], p["shard_size"]
    return [{"file": f"shards/shard_{j:05d}.npz", "num_sims": min(size, n - j * size), "seed": shard_seed(p["seed"], j),
             "sha256": None} for j in range((n + size - 1) // size)]


# ----------------------------------------------------------------------------------------------- worker side
_W: dict[str, Any] = {}


def _init_worker(shapes: list, p: dict[str, Any], cache_dir: str | None, out: str, child: bool = True) -> None:
    import signal

    if child:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and terminates the pool
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # pool.terminate() must just end the worker
        try:  # Linux: die with the parent (kill -9 of the parent must not leave workers running)
            import ctypes

            ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    _W.update(shapes=shapes, p=p, cache_dir=cache_dir, out=out, sim=None)


def _configs(p: dict[str, Any], cache_dir: str | None):
    from ..push import PushConfig
    from ..simulator import SimConfig

    sim_cfg = SimConfig(**{**p["sim"], "vhacd_cache_dir": cache_dir})
    push: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in p["push"].items()}
    return sim_cfg, PushConfig(**push)


def _decompose(index: int) -> tuple[int, float]:
    from ..simulator import convex_decomposition

    sim_cfg, _ = _configs(_W["p"], _W["cache_dir"])
    t = time.perf_counter()
    convex_decomposition(_W["shapes"][index], sim_cfg)
    return index, time.perf_counter() - t


def simulate_shard(j: int, shapes: list, p: dict[str, Any], cache_dir: str | None = None, sim=None) -> dict:
    """Arrays of shard j (pure function of the parameters and j)."""
    import numpy as np

    from ...data.format import stack_sims
    from ..push import simulate_push
    from ..simulator import Simulator

    sim_cfg, push_cfg = _configs(p, cache_dir)
    own = sim is None
    sim = Simulator(sim_cfg) if own else sim
    try:
        seed = shard_seed(p["seed"], j)
        first = j * p["shard_size"]
        count = min(p["shard_size"], p["num_sims"] - first)
        sims = []
        for i in range(count):
            k = first + i
            shape_index = k % len(shapes)  # round robin: every shape gets the same number of simulations
            rng = np.random.default_rng([seed, i])
            out = simulate_push(sim, shapes[shape_index], rng, push_cfg, vary_friction=p["vary_friction"],
                                num_frames=p["num_frames"])
            out.update(shape_index=np.int32(shape_index), sim_index=np.int64(k))
            sims.append(out)
        return stack_sims(sims)
    finally:
        if own:
            sim.close()


def _run_shard(j: int) -> tuple[int, str, int]:
    from ...data.format import write_npz
    from ..simulator import Simulator

    if _W.get("sim") is None:
        sim_cfg, _ = _configs(_W["p"], _W["cache_dir"])
        _W["sim"] = Simulator(sim_cfg)
    arrays = simulate_shard(j, _W["shapes"], _W["p"], _W["cache_dir"], _W["sim"])
    digest = write_npz(Path(_W["out"]) / f"shards/shard_{j:05d}.npz", arrays)
    return j, digest, len(arrays["shape_index"])


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """`kill PID` stops the generator like Ctrl-C: the pool is terminated, finished shards are kept."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def compute_shards(out: Path, shapes: list, p: dict, cache_dir: str | None, todo: list[int], concave: list[int],
                   total: int, workers: int, progress: bool, finished: Callable[[int, str, int], None]) -> None:
    """Compute the convex decompositions `concave`, then the shards `todo` (one process, or a fork pool of
    `workers`); `finished(j, sha256, num_sims)` runs in this process as each shard file is written."""
    import multiprocessing as mp

    from tqdm import tqdm

    bar = vbar = None
    if progress and concave:
        vbar = tqdm(total=len(concave), unit="shape", desc="convex decompositions (cached)", dynamic_ncols=True)
    if progress and todo:
        bar = tqdm(total=total, unit="sim", desc=f"generate {out.name}", dynamic_ncols=True)
    try:
        if workers == 1 or len(todo) + len(concave) <= 1:
            _init_worker(shapes, p, cache_dir, str(out), child=False)
            for i in concave:
                _decompose(i)
                if vbar:
                    vbar.update(1)
            for j in todo:
                j, digest, n = _run_shard(j)
                finished(j, digest, n)
                if bar:
                    bar.update(n)
        else:
            ctx = mp.get_context("fork")
            with ctx.Pool(min(workers, max(len(todo), len(concave))), initializer=_init_worker,
                          initargs=(shapes, p, cache_dir, str(out))) as pool:
                for _ in pool.imap_unordered(_decompose, concave):
                    if vbar:
                        vbar.update(1)
                for j, digest, n in pool.imap_unordered(_run_shard, todo):
                    finished(j, digest, n)
                    if bar:
                        bar.update(n)
    finally:
        for b in (vbar, bar):
            if b:
                b.close()
        if _W.get("sim") is not None:
            _W["sim"].close()
            _W["sim"] = None
