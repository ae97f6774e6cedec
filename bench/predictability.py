#!/usr/bin/env python3
"""How predictable is a push's final pose at all? The data's own simulator, re-run (issue 11's rotation goal).

    .venv/bin/python bench/predictability.py [--data data/pybullet_test] [--categories C ...] [--max-sequences 400]
        [--speed-error 0.02] [--checkpoint CKPT]

On the same test pushes `physdyn evaluate --max-sequences N` takes (evenly spaced over the test split), each push
is simulated again with the dataset's own shape (rebuilt from the manifest: the same mesh, convex decomposition,
scale, mass, friction and physics settings) from its recorded frame 0 (pose and velocities right after the
impulse), three ways:
  * replay: exactly that state;
  * push +/- e: the initial linear and angular velocities scaled by 1 + e and 1 - e (a push measured to within
    e; default 2 %);
and the checkpoint's roll-outs (physdyn evaluate's) for reference. Over the recorded pushes that do not topple:
the final (60 steps, 4 s) position and rotation differences from the recording, median and p90.
The spread between the recording and a replay or a 2 % different push is the part of the final pose that no
predictor reading the cloud and a measured push can be expected to recover.
Prints a table; the last line is one JSON object {n, replay: {pos_median_cm, pos_p90_cm, rot_median_deg,
rot_p90_deg}, push_plus: {...}, push_minus: {...}, model: {...}, speed_error}.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
HORIZON = 60


def final_errors(pos: np.ndarray, quat: np.ndarray, true_pos: np.ndarray, true_quat: np.ndarray) -> dict:
    from scipy.spatial.transform import Rotation

    d_pos = np.linalg.norm(pos - true_pos, axis=1) * 100
    d_rot = np.degrees((Rotation.from_quat(true_quat) * Rotation.from_quat(quat).inv()).magnitude())
    def pair(x: np.ndarray) -> tuple[float, float]:
        return round(float(np.median(x)), 2), round(float(np.percentile(x, 90)), 2)

    (pm, p9), (rm, r9) = pair(d_pos), pair(d_rot)
    return {"pos_median_cm": pm, "pos_p90_cm": p9, "rot_median_deg": rm, "rot_p90_deg": r9}


def resimulate(sims, index: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Final (HORIZON) positions and orientations of the pushes `index` re-simulated with their own shapes."""
    from physdyn_ros.sim import SimConfig, Simulator, simulate_from_state
    from physdyn_ros.sim.generation.workers import build_shapes

    gen = sims.manifest["generator"]
    shapes = build_shapes(gen)
    config = SimConfig(**gen["sim"])  # the generator's physics (the convex decompositions are cached)
    pos, quat = [], []
    with Simulator(config) as sim:
        for i in index:
            shape = shapes[int(sims.shape_index[i])]
            if shape.name != str(sims.shape_id[i]):
                raise ValueError(f"shape {shape.name} rebuilt for {sims.shape_id[i]}: the manifest's shapes differ")
            rec = simulate_from_state(shape, sims.scale[i], sims.pos[i, 0], sims.quat[i, 0],
                                      sims.lin_vel[i, 0] * factor, sims.ang_vel[i, 0] * factor,
                                      friction=float(sims.friction[i]), num_frames=HORIZON + 1, config=config, sim=sim)
            pos.append(rec["pos"][HORIZON])
            quat.append(rec["quat"][HORIZON])
            sim.remove()
    return np.asarray(pos), np.asarray(quat)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="data/pybullet_test")
    ap.add_argument("--categories", nargs="+", default=None, help="only these shape categories (as evaluate)")
    ap.add_argument("--max-sequences", type=int, default=400)
    ap.add_argument("--speed-error", type=float, default=0.02, help="relative error of the measured push")
    ap.add_argument("--checkpoint", default=str(ROOT / "physdyn_ros" / "models" / "default.pt"))
    args = ap.parse_args()
    if not 0.0 < args.speed_error < 0.5:
        raise SystemExit(f"--speed-error must be in (0, 0.5), got {args.speed_error}")
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import model_rollouts
    from physdyn_ros.learn.windows import load_sims

    torch.set_num_threads(1)
    sims = load_sims(args.data, ["test"], categories=args.categories)
    index = np.arange(len(sims))
    if args.max_sequences < len(index):  # physdyn evaluate's choice of sequences
        index = np.linspace(0, len(sims) - 1, args.max_sequences).astype(np.int64)
    index = index[sims.topple_index[index] < 0]
    true_pos, true_quat = sims.pos[index, HORIZON], sims.quat[index, HORIZON]
    out: dict = {"n": int(len(index)), "speed_error": args.speed_error}
    t0 = time.perf_counter()
    for name, factor in (("replay", 1.0), ("push_plus", 1.0 + args.speed_error),
                         ("push_minus", 1.0 - args.speed_error)):
        out[name] = final_errors(*resimulate(sims, index, factor), true_pos, true_quat)
    sim_s = time.perf_counter() - t0
    model, _ = load_model(args.checkpoint)
    traj = model_rollouts(model, sims, index, HORIZON)
    out["model"] = final_errors(traj.pos[:, HORIZON], traj.quat[:, HORIZON], true_pos, true_quat)
    print(f"{args.data}: {out['n']} test pushes that do not topple (of {args.max_sequences}); final pose after "
          f"{HORIZON} steps against the recording ({sim_s:.0f} s of simulation)")
    print("| run | position cm, median / p90 | rotation deg, median / p90 |\n|---|---|---|")
    for name, label in (("replay", "the same simulator, same shape, same state"),
                        ("push_plus", f"the same, push +{args.speed_error:.0%}"),
                        ("push_minus", f"the same, push -{args.speed_error:.0%}"),
                        ("model", f"model {Path(args.checkpoint).name}")):
        e = out[name]
        print(f"| {label} | {e['pos_median_cm']} / {e['pos_p90_cm']} | {e['rot_median_deg']} / {e['rot_p90_deg']} |")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
