"""How far pushes slide, by initial speed: truth, the model fed the true velocities, and the model's roll-out.

    .venv/bin/python bench/speed_bins.py [--model PATH] [--data data/combined] [--per-bin 120] [--horizon 30]

Non-toppling test-split sequences, binned by initial horizontal speed. Per bin, medians of: the true travel
after `horizon` steps; the travel the model predicts with the true velocities fed at every step (teacher
forcing); its closed-loop roll-out travel; and the speed left in the roll-out's fed-back velocity at the end
against the speed of its last predicted position step (both should be ~0 once the object rests).
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

from physdyn_ros.learn.checkpoint import load_model
from physdyn_ros.learn.windows import load_sims, sequences
from physdyn_ros.resources import DEFAULT_MODEL

BINS = ((0.0, 0.4), (0.4, 0.8), (0.8, 1.2), (1.2, 2.0), (2.0, 4.0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default=str(DEFAULT_MODEL))
    ap.add_argument("--data", default="data/combined")
    ap.add_argument("--per-bin", type=int, default=120)
    ap.add_argument("--horizon", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    model, ckpt = load_model(args.model)
    model.eval()
    sims = load_sims(args.data, ("test",))
    v0 = np.linalg.norm(sims.lin_vel[:, 0, :2], axis=1)
    dt = float(sims.dt)
    print(f"model {ckpt['model_id']}, {args.data} test split, {args.horizon} steps, medians per bin")
    print("| initial speed m/s | n | true travel cm | teacher-forced cm | roll-out cm | "
          "roll-out end: velocity channel / position step m/s |")
    print("|---|---|---|---|---|---|")
    for lo, hi in BINS:
        idx = np.flatnonzero((v0 >= lo) & (v0 < hi) & (sims.topple_index < 0))[:args.per_bin]
        if not len(idx):
            continue
        seq = sequences(sims, args.horizon, model.cfg.num_points, idx)
        with torch.inference_mode():
            feature = model.encode(seq["cloud"])
            forced = model.denormalize(model.teacher_forced(feature, seq["vel"][:, :-1], seq["angvel"][:, :-1]))
            roll = model.rollout(feature, seq["vel"][:, 0], seq["angvel"][:, 0], args.horizon)

        def travel(d_pos: torch.Tensor) -> float:
            return 100 * float(d_pos[..., :2].sum(1).norm(dim=-1).median())

        end_v = float(roll["vel"][:, -1, :2].norm(dim=-1).median())
        end_step = float(roll["d_pos"][:, -1, :2].norm(dim=-1).median()) / dt
        print(f"| {lo:.1f}-{hi:.1f} | {len(idx)} | {travel(seq['d_pos']):.1f} | {travel(forced['d_pos']):.1f} | "
              f"{travel(roll['d_pos']):.1f} | {end_v:.3f} / {end_step:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
