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
"""Latency and throughput of the Predictor against pybullet and the machine's matmul peak, in one run, for each
roll-out precision the CPU has.

    .venv/bin/python bench/bench_predictor.py [--model PATH] [--repeats 200] [--rounds 5] [--batch 1024]
        [--precision auto|fp32|bf16] [--precisions fp32,bf16]

Everything that is compared is measured in the same process, interleaved in --rounds rounds (a shared machine's
load then weighs on both sides of a ratio alike), with torch on one thread:
* CPU: the flags the kernels' libraries can use (avx2, fma, avx512f, avx512_bf16, amx_tile, amx_bf16, as lscpu
  names them) and whether the CPU has bf16 arithmetic that oneDNN may use (learn/precision.cpu_has_bf16: not
  under an ONEDNN_MAX_CPU_ISA cap below bf16; `--precisions fp32,bf16` times the emulated bf16 there).
* latency: one 60-step roll-out at batch 1 from an encoded ShapeCode (Predictor.rollout: the ROS predictor's and
  planner's per-query cost), p50 / p99; also encode + roll-out from a raw cloud. Batch 1 runs in float32 in
  every precision: the C kernel where it is built (learn/native.py), with the numpy kernel timed beside it.
* pybullet: physdyn_ros.sim.simulate_from_state re-simulating the same pushes (convex hull of the same clouds, the
  dataset generator's physics settings; pybullet is single-threaded), median ms per push.
* per-core figures (the batch, the matmul peaks, pybullet per core) count the thread's CPU time (time.thread_time):
  on a shared machine a 0.5 s batch is preempted far more often than a 30 ms matmul, which wall time would count
  against the batch. Latencies (batch 1, pybullet_push_ms, msg_build_ms) are wall time.
* batched, per precision (fp32, and bf16 where the CPU has bf16 arithmetic or --precisions asks for it):
  trajectories per CPU-second of rollout_batch at --batch on one thread (the median over rounds), its FLOP/s
  (FLOPs of the matrix products per roll-out, from the model's layer sizes: elementwise work not counted) as a
  fraction of that precision's matmul peak, the same per core against pybullet; the model's roll-out alone
  (DynamicsModel.rollout_raw: no input checks, frames, topple head or integration) likewise; and the LSTM's two
  matrix products of one step at --batch alone (lstm_products_ms: the kernel's shapes), so that the kernel's
  time splits into products and elementwise work. Where the bf16 kernel's cell, head and prior run in C
  (learn/cell_bf16.py), the same bf16 batch with the TorchScript kernel's is timed beside it.
  --batch-threads > 1 adds a multi-thread line.
* peaks: a plain 1024^3 matmul (torch) in fp32 and in bf16 on one thread, best of 3 just before and 3 just after
  each round's batch of that precision; each round's fraction of peak uses that round's peak, the median over
  rounds is reported.
* msg_build_ms: physdyn_ros.ros.trajectory_to_msg of a 60-step trajectory (61 states), p50.
The headline figures are those of the precision the Predictor uses at --batch (--precision, default auto: bf16
where the CPU has bf16 arithmetic). Goals: on a CPU with bf16 arithmetic batched roll-outs >= 60x pybullet per
core and >= 50 % of the bf16 matmul peak; batch 1 >= 5x faster than a pybullet push on every CPU.
The last line is one JSON object: rollout_b1_p50_ms, rollout_b1_p99_ms, pybullet_push_ms (wall),
pybullet_push_cpu_ms, b1_speedup_vs_pybullet, b1_kernel (c or numpy), rollout_b1_numpy_p50_ms and
b1_numpy_speedup_vs_pybullet (the numpy kernel timed beside the C kernel), batched_traj_per_s_1thread,
batched_speedup_vs_pybullet_per_core, matmul_gflops_1thread, batched_gflops_1thread, batched_fraction_of_peak,
kernel_fraction_of_peak (of the precision used), mflop_per_rollout, msg_build_ms, precision (used), cpu_flags,
bf16_arithmetic, per_precision (each precision's batched, kernel and product figures and its peak; a batch's
time split into the products, the model's elementwise work and step overhead, and the Predictor's post-processing,
against the time a batch may take at half the peak; for bf16 its cell, c or torchscript, and
batched_traj_per_s_torchscript_cell), batch, horizon, threads. A figure that could not
be measured (no pybullet, no rclpy, no bf16 run) is null, never a traceback.
Without a shipped model (physdyn_ros/models/default.pt) the default config is timed with random weights: speed
does not depend on the weights.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from contextlib import contextmanager
from typing import Any, Iterator, Optional

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


def rollout_flops(cfg: Any, steps: int) -> int:
    """FLOPs (2 per multiply-add) of the matrix products of one roll-out of `steps` steps.

    LSTM: per step layer 0 multiplies [v, w] (6) and h_0 (H) by its 4 H gate columns (the shape-feature term is
    constant: once per roll-out), layer l > 0 [h_{l-1}, h_l] (2 H), the head H -> 13, input_skip 6 -> 13.
    MLP baseline: its layers on [v, w, feature] every step.
    """
    f, h = cfg.shape_mlp[-1], cfg.hidden_size
    skip = 2 * 6 * 13 if cfg.input_skip else 0
    if cfg.cell == "lstm":
        per_step = 2 * (6 + h) * 4 * h + (cfg.num_layers - 1) * 2 * (2 * h) * 4 * h + 2 * h * 13 + skip
        return steps * per_step + 2 * f * 4 * h
    dims = [6 + f] + [h] * (cfg.mlp_layers - 1) + [13]
    return steps * (sum(2 * a * b for a, b in zip(dims[:-1], dims[1:])) + skip)


def pct(samples: list[float], q: float) -> float:
    return float(np.percentile(samples, q) * 1e3)


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


class PyBullet:
    """simulate_from_state on one shared simulator; None-safe when pybullet is not installed."""

    def __init__(self, horizon: int) -> None:
        self.horizon = horizon
        self.error = ""
        try:
            from physdyn_ros.sim import SimConfig, Simulator, simulate_from_state
        except ImportError as exc:
            self.sim = None
            self.error = str(exc)
            return
        self.config = SimConfig(collision="hull")
        self.simulate = simulate_from_state
        self.sim = Simulator(self.config)

    def push(self, c: dict) -> tuple[float, float]:
        """(wall, CPU) seconds of one simulated push."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.simulate(c["shape"].points, c["scale"], c["pos"], c["quat"], c["lin_vel"], c["ang_vel"],
                      num_frames=self.horizon + 1, config=self.config, sim=self.sim)
        return time.perf_counter() - t0, time.thread_time() - c0

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()


def matmul_peak(dtype: Any) -> float:
    """GFLOP/s of the best of 3 plain 1024^3 matmuls (torch, current thread setting)."""
    import torch

    a, b = torch.randn(1024, 1024, dtype=dtype), torch.randn(1024, 1024, dtype=dtype)
    a @ b
    best = min(_cpu_timed(lambda: a @ b) for _ in range(3))
    return 2 * 1024**3 / best / 1e9


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _cpu_timed(fn) -> float:
    """CPU time of this thread (torch runs on it with one thread): time preempted by other processes excluded."""
    t0 = time.thread_time()
    fn()
    return time.thread_time() - t0


def kernel_inputs(pred: Any, shapes: list, v: np.ndarray, w: np.ndarray) -> tuple:
    """Model inputs of a batch (features, velocities in frame C) for timing the model without the Predictor."""
    import torch

    from physdyn_ros.learn.frames import world_to_c

    headings = np.array([c.heading for c in shapes])
    f32 = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float32))  # noqa: E731
    dim = pred._model.feature_dim  # the dynamics network's part of the code (a topple head appends descriptors)
    return (f32(np.stack([c.feature[:dim] for c in shapes])), f32(world_to_c(v, headings)),
            f32(world_to_c(w, headings)))


def b1_parts(pred: Any, codes: list, cases: list, horizon: int) -> list:
    """Per case, timers of the parts of a batch-1 Predictor.rollout: the model's roll-out alone
    (DynamicsModel.rollout_arrays: the numpy kernel with the sliding prior) and, for models with one, the whole-push
    topple head (learn/topple.py); the rest of Predictor.rollout is input checks, frames, the rules, integration."""
    feats, v, w = (t.numpy() for t in kernel_inputs(pred, codes, np.stack([c["lin_vel"] for c in cases]),
                                                     np.stack([c["ang_vel"] for c in cases])))
    dim = pred._model.feature_dim
    topple = getattr(pred._model, "topple", None)
    parts = []
    for k, code in enumerate(codes):
        def model(k: int = k) -> Any:
            return pred._model.rollout_arrays(feats[k:k + 1], v[k:k + 1], w[k:k + 1], horizon)

        def head(k: int = k, c: Any = code) -> Any:
            assert topple is not None  # only timed for models with the head
            return topple.assess(c.feature[None, :dim], c.feature[None, dim:], v[k:k + 1].astype(np.float64),
                                 w[k:k + 1].astype(np.float64))
        parts.append((model, None if topple is None else head))
    return parts


def kernel_rollout(pred: Any, inputs: tuple, horizon: int, precision: str = "fp32") -> Any:
    """DynamicsModel.rollout_raw alone (no input checks, frames or integration): the roll-out kernel."""
    import torch

    with torch.inference_mode():
        return pred._model.rollout_raw(*inputs, horizon, precision=precision)


@contextmanager
def torchscript_cell() -> Iterator[None]:
    """bf16 roll-outs with the TorchScript kernel's cell, head and prior where the C ones would run (timed beside)."""
    from physdyn_ros.learn import cell_bf16

    available = cell_bf16.available
    cell_bf16.available = lambda hidden: False
    try:
        yield
    finally:
        cell_bf16.available = available


def lstm_products(pred: Any, batch: int, precision: str) -> Optional[Any]:
    """A timer of the LSTM's matrix products of one step at `batch` rows in the kernel's shapes and precision
    (fp32: fused_lstm_rollout's addmm per layer; bf16: bf16_lstm_rollout's plain products), or None for a
    model without LSTM kernels."""
    import torch

    with torch.inference_mode():
        kernel = pred._model._kernel(pred._model._fast()) if pred._model.cfg.cell == "lstm" else {}
    if precision == "bf16" and "bf16_w" in kernel:
        weights = kernel["bf16_w"]
        rows = [torch.randn(batch, w.shape[0]).to(torch.bfloat16) for w in weights]
        outs = [torch.empty(batch, w.shape[1], dtype=torch.bfloat16) for w in weights]
        return lambda: [torch.mm(a, w, out=o) for a, w, o in zip(rows, weights, outs)]
    if precision == "fp32" and "w" in kernel:
        weights, biases = kernel["w"], kernel["b"]
        rows = [torch.randn(batch, w.shape[0]) for w in weights]
        outs = [torch.empty(batch, w.shape[1]) for w in weights]
        const0 = torch.randn(batch, weights[0].shape[1])  # layer 0's per-row bias (with the feature term)
        return lambda: [torch.addmm(const0 if i == 0 else b, a, w, out=o)
                        for i, (a, w, b, o) in enumerate(zip(rows, weights, biases, outs))]
    return None


def msg_build_samples(traj: Any, repeats: int) -> Optional[list[float]]:
    try:
        from physdyn_ros.ros.convert import ns_to_time
        from physdyn_ros.ros.trajectory import trajectory_to_msg
    except ImportError as exc:  # no ROS 2 Python packages in this environment
        print(f"trajectory_to_msg unavailable: {exc}")
        return None
    stamp = ns_to_time(1_700_000_000_000_000_000)
    trajectory_to_msg(traj, "table", stamp, "object", "model")
    return [_timed(lambda: trajectory_to_msg(traj, "table", stamp, "object", "model")) for _ in range(repeats)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model, else random weights)")
    ap.add_argument("--repeats", type=int, default=200, help="batch-1 roll-outs (split over the rounds)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved measurement rounds (default 5)")
    ap.add_argument("--horizon", type=int, default=60)
    ap.add_argument("--batch", type=int, default=1024, help="batch size of the throughput test (default 1024)")
    ap.add_argument("--batch-threads", type=int, default=1,
                    help="also time the batch on this many threads (default 1: only the one-thread figure)")
    ap.add_argument("--pybullet-trajectories", type=int, default=48, help="pushes simulated (split over the rounds)")
    ap.add_argument("--precision", default="auto", help="the Predictor's precision: auto (default), fp32, bf16")
    ap.add_argument("--precisions", default=None,
                    help="comma-separated precisions to time batched (default: fp32, and bf16 where the CPU has "
                         "bf16 arithmetic; bf16 on a CPU without it is emulated, slower)")
    args = ap.parse_args()

    import torch

    from physdyn_ros.learn import cell_bf16, native
    from physdyn_ros.learn.precision import REPORTED_FLAGS, check_precision, cpu_flags, cpu_has_bf16
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
    pred = Predictor.load(model_path, threads=1, precision=args.precision)
    cfg = pred._model.cfg
    flops = rollout_flops(cfg, args.horizon)
    bf16_cpu = cpu_has_bf16()
    flags = [f for f in REPORTED_FLAGS if f in cpu_flags()]
    precisions = (["fp32", "bf16"] if bf16_cpu else ["fp32"]) if args.precisions is None else \
        [check_precision(x.strip()) for x in args.precisions.split(",") if x.strip()]
    used = pred.batch_precision(args.batch)
    if used not in precisions:
        precisions.append(used)
    dtypes = {"fp32": torch.float32, "bf16": torch.bfloat16}
    twins = {}  # one Predictor per timed precision, sharing the model
    for prec in precisions:
        twins[prec] = copy.copy(pred)
        twins[prec].precision = prec
    print(f"model {pred.model_id}{note}; torch {torch.__version__}, numpy {np.__version__}, {os.cpu_count()} CPU(s); "
          f"{flops / 1e6:.2f} MFLOP per {args.horizon}-step roll-out")
    print(f"CPU flags: {' '.join(flags) or '(none of ' + ', '.join(REPORTED_FLAGS) + ')'}; bf16 arithmetic: "
          f"{'yes' if bf16_cpu else 'no'}; precision {args.precision}: batches of {args.batch} run in {used}; "
          f"timed: {', '.join(precisions)}; batch 1 runs in fp32")
    b1_kernel = "c" if native.use_c() else "numpy"
    c_cell = "bf16" in precisions and cell_bf16.available(pred._model.cfg.hidden_size)
    print(f"bf16 kernel's cell: c ({cell_bf16.status()}); the TorchScript cell is timed beside it" if c_cell
          else f"bf16 kernel's cell: TorchScript (the C cell: {cell_bf16.status()})")
    print(f"batch-1 kernel: {b1_kernel} ({native.status()}); the numpy kernel is timed beside it"
          if b1_kernel == "c" else f"batch-1 kernel: numpy (the C kernel: {native.status()})")
    if os.environ.get("OPENBLAS_CORETYPE"):
        print(f"note: OPENBLAS_CORETYPE={os.environ['OPENBLAS_CORETYPE']} (numpy's BLAS: the batch-1 path)")

    rounds = max(1, args.rounds)
    cases = make_cases(max(args.pybullet_trajectories, args.batch, 64))
    codes = [pred.encode(c["cloud"]) for c in cases[:64]]
    shapes = [codes[i % 64] for i in range(args.batch)]
    bv = np.stack([cases[i]["lin_vel"] for i in range(args.batch)])
    bw = np.stack([cases[i]["ang_vel"] for i in range(args.batch)])
    pyb = PyBullet(args.horizon)
    if pyb.sim is None:
        print(f"pybullet baseline unavailable: {pyb.error}")
    for i in range(10):  # warm-up
        pred.rollout(codes[i % 16], cases[i % 16]["lin_vel"], cases[i % 16]["ang_vel"], args.horizon)
    kernel_in = kernel_inputs(pred, shapes, bv, bw)
    products = {prec: lstm_products(pred, args.batch, prec) for prec in precisions}
    for prec in precisions:  # TorchScript optimises a function on its first calls
        for _ in range(2):
            twins[prec].rollout_batch(shapes, bv, bw, args.horizon)
            kernel_rollout(pred, kernel_in, args.horizon, prec)
    if pyb.sim is not None:
        pyb.push(cases[0])

    lat: list[float] = []
    lat_numpy: list[float] = []
    full: list[float] = []
    pyb_times: list[float] = []
    pyb_cpu: list[float] = []
    per: dict[str, dict[str, list[float]]] = {prec: {"rate": [], "kernel_rate": [], "peak": [], "fraction": [],
                                                     "kernel_fraction": [], "products": [], "ts_cell_rate": []}
                                              for prec in precisions}
    parts = b1_parts(pred, codes[:16], cases[:16], args.horizon)
    lat_model: list[float] = []
    lat_head: list[float] = []
    per_round = max(1, args.repeats // rounds)
    pushes = max(1, args.pybullet_trajectories // rounds)
    for r in range(rounds):
        torch.set_num_threads(1)
        # pybullet pushes and batch-1 roll-outs alternate, so that both see the same load
        for j in range(pushes):
            if pyb.sim is not None:
                wall, cpu = pyb.push(cases[r * pushes + j])
                pyb_times.append(wall)
                pyb_cpu.append(cpu)
            for i in range(j * per_round // pushes, (j + 1) * per_round // pushes):
                k = (r * per_round + i) % 16
                lat.append(_timed(lambda: pred.rollout(codes[k], cases[k]["lin_vel"], cases[k]["ang_vel"],
                                                       args.horizon)))
                lat_model.append(_timed(parts[k][0]))
                if b1_kernel == "c":  # the same roll-out through the numpy kernel, interleaved
                    chosen = os.environ.get(native.ENV)
                    os.environ[native.ENV] = "numpy"
                    lat_numpy.append(_timed(lambda: pred.rollout(codes[k], cases[k]["lin_vel"], cases[k]["ang_vel"],
                                                                 args.horizon)))
                    if chosen is None:
                        os.environ.pop(native.ENV)
                    else:
                        os.environ[native.ENV] = chosen
                if parts[k][1] is not None:
                    lat_head.append(_timed(parts[k][1]))
        for i in range(max(1, min(per_round, 100 // rounds))):
            k = i % 16
            full.append(_timed(lambda: pred.rollout(cases[k]["cloud"], cases[k]["lin_vel"], cases[k]["ang_vel"],
                                                    args.horizon)))
        line = [f"round {r + 1}/{rounds}: batch-1 p50 {pct(lat[-per_round:], 50):.2f} ms"
                + (f", pybullet {pct(pyb_times[-pushes:], 50):.1f} ms/push" if pyb_times else "")]
        for prec in precisions:
            # the batch between two peak measurements of its precision; the round's peak is the better of the two
            f = per[prec]
            peak = matmul_peak(dtypes[prec])
            t = _cpu_timed(lambda: twins[prec].rollout_batch(shapes, bv, bw, args.horizon))
            t_kernel = _cpu_timed(lambda: kernel_rollout(pred, kernel_in, args.horizon, prec))
            if prec == "bf16" and c_cell:  # the same batch with the TorchScript cell, between the same peaks
                with torchscript_cell():
                    f["ts_cell_rate"].append(args.batch / _cpu_timed(
                        lambda: twins[prec].rollout_batch(shapes, bv, bw, args.horizon)))
            if products[prec] is not None:
                f["products"].append(min(_cpu_timed(products[prec]) for _ in range(5)))
            peak = max(peak, matmul_peak(dtypes[prec]))
            f["peak"].append(peak)
            f["rate"].append(args.batch / t)
            f["kernel_rate"].append(args.batch / t_kernel)
            f["fraction"].append(args.batch / t * flops / 1e9 / peak)
            f["kernel_fraction"].append(args.batch / t_kernel * flops / 1e9 / peak)
            line.append(f"{prec}: matmul {peak:.0f} GFLOP/s, batch {args.batch} {f['rate'][-1]:.0f} traj/s "
                        f"({f['fraction'][-1]:.0%} of peak; model alone {f['kernel_fraction'][-1]:.0%})")
        print("; ".join(line))

    p50, p99 = pct(lat, 50), pct(lat, 99)
    pyb_ms = pct(pyb_times, 50) if pyb_times else None
    pyb_cpu_s = float(np.median(pyb_cpu)) if pyb_cpu else None
    print(f"latency, {args.horizon}-step roll-out at batch 1 from a ShapeCode: p50 {p50:.2f} ms, p99 {p99:.2f} ms "
          "(Predictor.rollout: the shape feature is encoded once per object, not counted)")
    if lat_numpy:
        print(f"  the same roll-outs through the numpy kernel: p50 {pct(lat_numpy, 50):.2f} ms "
              f"({pct(lat_numpy, 50) / p50:.2f}x the {b1_kernel} kernel's)")
    print(f"  of which the model's roll-out alone ({b1_kernel} kernel + sliding prior): p50 {pct(lat_model, 50):.2f} ms"
          + (f"; the whole-push topple head: p50 {pct(lat_head, 50):.2f} ms" if lat_head else "")
          + "; the rest: input checks, frames, consistency rules, integration")
    print(f"latency, encode ({len(cases[0]['cloud'])} points) + roll-out:        p50 {pct(full, 50):.2f} ms, "
          f"p99 {pct(full, 99):.2f} ms")
    b1_speedup = None
    if pyb_ms is not None:
        b1_speedup = pyb_ms / p50
        print(f"pybullet (simulate_from_state, convex hull, {pyb.config.physics_hz} Hz, 1 thread): {pyb_ms:.2f} ms "
              f"per push ({1e3 / pyb_ms:.0f} trajectories/s); batch-1 roll-out {b1_speedup:.1f}x faster "
              f"(goal >= 5x: {'met' if b1_speedup >= 5 else 'NOT met'})")
    summary: dict[str, dict[str, Any]] = {}
    r3 = lambda x: None if x is None else round(float(x), 3)  # noqa: E731
    for prec in precisions:
        f = per[prec]
        rate, kernel_rate = float(np.median(f["rate"])), float(np.median(f["kernel_rate"]))
        peak, fraction = float(max(f["peak"])), float(np.median(f["fraction"]))
        kernel_fraction = float(np.median(f["kernel_fraction"]))
        ceiling_rate = peak * 1e9 / flops  # trajectories/s if every FLOP of the products ran at the matmul peak
        prod_ms = 1e3 * float(np.median(f["products"])) if f["products"] else None
        speedup = rate * pyb_cpu_s if pyb_cpu_s else None
        kernel_speedup = kernel_rate * pyb_cpu_s if pyb_cpu_s else None
        goals = ""
        if prec == "bf16" and bf16_cpu:
            goals = (f" (goals >= 50 % of peak: {'met' if fraction >= 0.5 else 'NOT met'}"
                     + (f", >= 60x pybullet: {'met' if speedup >= 60 else 'NOT met'}" if speedup else "") + ")")
        print(f"batched roll-outs in {prec}, batch {args.batch}, 1 thread: {rate:.0f} trajectories/s = "
              f"{rate * flops / 1e9:.1f} GFLOP/s, {fraction:.0%} of the {prec} matmul peak {peak:.0f} GFLOP/s"
              + (f"; {speedup:.0f}x pybullet per core" if speedup else "") + goals)
        print(f"  the model alone (rollout_raw): {kernel_rate:.0f} trajectories/s, {kernel_fraction:.0%} of the peak"
              + (f", {kernel_speedup:.0f}x pybullet per core" if kernel_speedup else "")
              + (f"; its LSTM products alone {prod_ms:.2f} ms per step = "
                 f"{args.horizon * prod_ms / (1e3 * args.batch / kernel_rate):.0%} of its time over {args.horizon} "
                 "steps" if prod_ms else "")
              + (f"; ceiling at the peak {ceiling_rate:.0f} trajectories/s = {ceiling_rate * pyb_cpu_s:.0f}x pybullet"
                 if pyb_cpu_s else ""))
        # where the time of a batch goes, against what the whole batch may take at half the matmul peak
        half_peak_ms = 1e3 * args.batch * flops / (0.5 * peak * 1e9)
        batch_ms, kernel_ms = 1e3 * args.batch / rate, 1e3 * args.batch / kernel_rate
        elementwise_ms = kernel_ms - args.horizon * prod_ms if prod_ms is not None else None
        print(f"  per batch of {args.batch}: {batch_ms:.1f} ms = the model {kernel_ms:.1f} ms"
              + (f" (products {args.horizon * prod_ms:.1f}, elementwise work and step overhead "
                 f"{elementwise_ms:.1f})" if elementwise_ms is not None else "")
              + f" + the Predictor's frames, rules and topple head {batch_ms - kernel_ms:.1f} (medians of separate "
              f"runs: their difference is noisy); at 50 % of the peak the whole batch may take {half_peak_ms:.1f} ms")
        ts_rate = float(np.median(f["ts_cell_rate"])) if f["ts_cell_rate"] else None
        if ts_rate:
            print(f"  the same batch with the TorchScript cell, head and prior: {ts_rate:.0f} trajectories/s, "
                  f"{ts_rate * flops / 1e9 / peak:.0%} of the peak (the C ones {rate / ts_rate:.2f}x)")
        summary[prec] = {"batched_traj_per_s_1thread": r3(rate), "batched_gflops_1thread": r3(rate * flops / 1e9),
                         "batched_fraction_of_peak": r3(fraction), "batched_speedup_vs_pybullet_per_core": r3(speedup),
                         "kernel_traj_per_s_1thread": r3(kernel_rate), "kernel_fraction_of_peak": r3(kernel_fraction),
                         "kernel_speedup_vs_pybullet_per_core": r3(kernel_speedup), "matmul_gflops_1thread": r3(peak),
                         "lstm_products_ms_per_step": r3(prod_ms), "ceiling_traj_per_s_1thread": r3(ceiling_rate),
                         "batch_ms": r3(batch_ms), "elementwise_ms_per_batch": r3(elementwise_ms),
                         "postprocess_ms_per_batch": r3(batch_ms - kernel_ms), "half_peak_batch_ms": r3(half_peak_ms)}
        if prec == "bf16":
            summary[prec].update(cell="c" if c_cell else "torchscript",
                                 batched_traj_per_s_torchscript_cell=r3(ts_rate))
    if len(precisions) > 1 and "fp32" in summary:
        for prec in precisions:
            if prec != "fp32":
                a, b = summary["fp32"], summary[prec]
                ratio = lambda key: b[key] / a[key]  # noqa: E731
                step = a["lstm_products_ms_per_step"], b["lstm_products_ms_per_step"]
                print(f"{prec} against fp32, side by side: batched {ratio('batched_traj_per_s_1thread'):.2f}x, the "
                      f"model alone {ratio('kernel_traj_per_s_1thread'):.2f}x, matmul peak "
                      f"{ratio('matmul_gflops_1thread'):.2f}x"
                      + (f", the LSTM products of a step {step[0] / step[1]:.2f}x" if all(step) else ""))
    if args.batch_threads > 1:
        torch.set_num_threads(args.batch_threads)
        pred.rollout_batch(shapes, bv, bw, args.horizon)
        t = min(_timed(lambda: pred.rollout_batch(shapes, bv, bw, args.horizon)) for _ in range(rounds))
        print(f"batched roll-outs in {used}, batch {args.batch}, {args.batch_threads} threads: {args.batch / t:.0f} "
              f"trajectories/s (wall clock)")
        torch.set_num_threads(1)
    traj = pred.rollout(codes[0], cases[0]["lin_vel"], cases[0]["ang_vel"], args.horizon)
    msg = msg_build_samples(traj, max(20, args.repeats // 2))
    msg_ms = pct(msg, 50) if msg else None
    if msg_ms is not None:
        print(f"trajectory_to_msg, {len(traj.positions)} states: p50 {msg_ms:.2f} ms")
    pyb.close()
    if tmp is not None:
        tmp.cleanup()
    head = summary[used]
    print(json.dumps({
        "rollout_b1_p50_ms": r3(p50), "rollout_b1_p99_ms": r3(p99), "pybullet_push_ms": r3(pyb_ms),
        "pybullet_push_cpu_ms": r3(pct(pyb_cpu, 50) if pyb_cpu else None),
        "b1_speedup_vs_pybullet": r3(b1_speedup), "b1_kernel": b1_kernel,
        "rollout_b1_numpy_p50_ms": r3(pct(lat_numpy, 50)) if lat_numpy else r3(p50),
        "b1_numpy_speedup_vs_pybullet": r3(pyb_ms / pct(lat_numpy, 50)) if lat_numpy and pyb_ms else
        (r3(b1_speedup) if b1_kernel == "numpy" else None),
        "batched_traj_per_s_1thread": head["batched_traj_per_s_1thread"],
        "batched_speedup_vs_pybullet_per_core": head["batched_speedup_vs_pybullet_per_core"],
        "matmul_gflops_1thread": head["matmul_gflops_1thread"],
        "batched_gflops_1thread": head["batched_gflops_1thread"],
        "batched_fraction_of_peak": head["batched_fraction_of_peak"],
        "kernel_fraction_of_peak": head["kernel_fraction_of_peak"], "mflop_per_rollout": r3(flops / 1e6),
        "rollout_b1_model_p50_ms": r3(pct(lat_model, 50)),
        "topple_head_b1_p50_ms": r3(pct(lat_head, 50) if lat_head else None), "msg_build_ms": r3(msg_ms),
        "precision": used, "precision_setting": args.precision, "cpu_flags": flags, "bf16_arithmetic": bf16_cpu,
        "per_precision": summary, "batch": args.batch, "horizon": args.horizon, "threads": 1}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
