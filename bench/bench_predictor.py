#!/usr/bin/env python3
"""Latency and throughput of the Predictor against pybullet on the same trajectories.

    .venv/bin/python bench/bench_predictor.py [--model PATH] [--threads 1] [--repeats 200]

* latency: one 60-step roll-out at batch 1 from an encoded ShapeCode (the ROS predictor's and planner's
  per-query cost), p50 / p99 over --repeats calls; also encode + roll-out from a raw cloud.
* throughput: trajectories per second of rollout_batch at batch 64 / 256 / 1024.
* pybullet: physdyn_ros.sim.simulate_from_state re-simulating the same initial states (convex hull of the same
  clouds, the dataset generator's physics settings) on one thread, trajectories per second.
Goals: one roll-out <= 5 ms; batched >= 100x pybullet's trajectories per second.
Without a shipped model (physdyn_ros/models/default.pt) the default config is timed with random weights:
speed does not depend on the weights.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def random_weights_checkpoint(config: Path, path: Path) -> None:
    """A checkpoint of the default architecture with random weights (for timing only)."""
    import torch

    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig
    from physdyn_ros.learn.train import load_config

    cfg = load_config(config)
    torch.manual_seed(0)
    stats = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))
    model = DynamicsModel(ModelConfig.from_dict(cfg["model"]), stats)
    save_checkpoint(path, model=model, config=cfg, dataset={}, include_rng=False)


def percentiles(samples: list[float]) -> tuple[float, float]:
    return float(np.percentile(samples, 50) * 1e3), float(np.percentile(samples, 99) * 1e3)


def make_cases(n: int, seed: int = 0) -> list[dict]:
    """n initial states of procedural shapes (several categories), pushed moderately hard."""
    from physdyn_ros import geometry as geo
    from physdyn_ros.shapes import generate_shapes

    rng = np.random.default_rng(seed)
    shapes = [s for cat in ("box", "cylinder", "bottle", "speaker") for s in generate_shapes(cat, 4, seed=0)]
    cases = []
    for i in range(n):
        shape = shapes[i % len(shapes)]
        scale = rng.uniform(0.6, 1.4, 3)
        yaw = rng.uniform(-np.pi, np.pi)
        quat = geo.yaw_quat(yaw)
        lo = (shape.vertices[:, 2] * scale[2]).min()
        pos = np.array([0.0, 0.0, -lo + 0.001])
        speed, az = rng.uniform(0.3, 1.5), rng.uniform(-np.pi, np.pi)
        cases.append({"shape": shape, "scale": scale, "pos": pos, "quat": quat,
                      "lin_vel": np.array([speed * np.cos(az), speed * np.sin(az), 0.0]),
                      "ang_vel": np.array([0.0, 0.0, rng.uniform(-4, 4)]),
                      "cloud": geo.quat_rotate(quat, shape.points * scale) + pos})
    return cases


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model, else random weights)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads for the latency test (default 1)")
    ap.add_argument("--batch-threads", type=int, default=None,
                    help="torch threads for the batched test (default: --threads, then also os.cpu_count())")
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--horizon", type=int, default=60)
    ap.add_argument("--pybullet-trajectories", type=int, default=64)
    args = ap.parse_args()

    import torch

    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import DEFAULT_MODEL

    tmp = None
    model_path = args.model
    if model_path is None and DEFAULT_MODEL.is_file():
        model_path = str(DEFAULT_MODEL)
    note = ""
    if model_path is None:
        tmp = tempfile.TemporaryDirectory()
        model_path = str(Path(tmp.name) / "random.pt")
        random_weights_checkpoint(ROOT / "config" / "model_default.yaml", Path(model_path))
        note = " (no shipped model: default architecture, random weights)"
    pred = Predictor.load(model_path, threads=args.threads)
    print(f"model {pred.model_id}{note}; torch {torch.__version__}, {torch.get_num_threads()} thread(s), "
          f"{os.cpu_count()} CPU(s)")

    cases = make_cases(max(args.pybullet_trajectories, 1024))
    codes = [pred.encode(c["cloud"]) for c in cases[:16]]
    c0 = cases[0]
    # ---- latency at batch 1
    lat = []
    for i in range(args.repeats + 10):
        t0 = time.perf_counter()
        pred.rollout(codes[i % 16], cases[i % 16]["lin_vel"], cases[i % 16]["ang_vel"], args.horizon)
        if i >= 10:
            lat.append(time.perf_counter() - t0)
    full = []
    for i in range(min(args.repeats, 100)):
        t0 = time.perf_counter()
        pred.rollout(cases[i % 16]["cloud"], c0["lin_vel"], c0["ang_vel"], args.horizon)
        full.append(time.perf_counter() - t0)
    p50, p99 = percentiles(lat)
    f50, f99 = percentiles(full)
    print(f"latency, {args.horizon}-step roll-out at batch 1 from a ShapeCode: p50 {p50:.2f} ms, p99 {p99:.2f} ms "
          f"(goal <= 5 ms: {'met' if p50 <= 5 else 'NOT met'})")
    print(f"latency, encode ({len(c0['cloud'])} points) + roll-out:        p50 {f50:.2f} ms, p99 {f99:.2f} ms")

    # ---- pybullet on the same trajectories
    pyb_rate = None
    try:
        from physdyn_ros.sim import SimConfig, Simulator, simulate_from_state

        config = SimConfig(collision="hull")
        n = args.pybullet_trajectories
        with Simulator(config) as sim:
            simulate_from_state(c0["shape"].points, c0["scale"], c0["pos"], c0["quat"], c0["lin_vel"],
                                c0["ang_vel"], num_frames=args.horizon + 1, config=config, sim=sim)  # warm-up
            t0 = time.perf_counter()
            for c in cases[:n]:
                simulate_from_state(c["shape"].points, c["scale"], c["pos"], c["quat"], c["lin_vel"], c["ang_vel"],
                                    num_frames=args.horizon + 1, config=config, sim=sim)
            pyb_rate = n / (time.perf_counter() - t0)
        print(f"pybullet (simulate_from_state, convex hull, {config.physics_hz} Hz, 1 thread): "
              f"{pyb_rate:.0f} trajectories/s ({1e3 / pyb_rate:.1f} ms each)")
    except ImportError as exc:
        print(f"pybullet baseline unavailable: {exc}")

    # ---- batched throughput
    thread_options = [args.batch_threads] if args.batch_threads else sorted({args.threads, os.cpu_count() or 1})
    all_codes = [pred.encode(c["cloud"]) for c in cases[:64]]
    for threads in thread_options:
        torch.set_num_threads(threads)
        for b in (64, 256, 1024):
            shapes = [all_codes[i % 64] for i in range(b)]
            v = np.stack([cases[i]["lin_vel"] for i in range(b)])
            w = np.stack([cases[i]["ang_vel"] for i in range(b)])
            pred.rollout_batch(shapes, v, w, args.horizon)  # warm-up for this batch size
            reps = max(1, int(2048 // b))
            t0 = time.perf_counter()
            for _ in range(reps):
                pred.rollout_batch(shapes, v, w, args.horizon)
            rate = b * reps / (time.perf_counter() - t0)
            ratio = f", {rate / pyb_rate:.0f}x pybullet (goal >= 100x)" if pyb_rate else ""
            print(f"batched roll-outs, batch {b:4d}, {threads} thread(s): {rate:8.0f} trajectories/s{ratio}")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
