#!/usr/bin/env python3
"""How predictable is a push's final pose at all? The data's own simulator, re-run (issue 11's rotation goal).

    .venv/bin/python bench/predictability.py [--data data/pybullet_test] [--categories C ...] [--max-sequences 400]
        [--speed-error 0.02] [--checkpoint CKPT] [--vhacd-resolution 0]

On the same test pushes `physdyn evaluate --max-sequences N` takes (evenly spaced over the test split), each push
is simulated again with the dataset's own shape (rebuilt from the manifest: the same mesh, convex decomposition,
scale, mass, friction and physics settings) from its recorded frame 0 (pose and velocities right after the
impulse), three ways:
  * replay: exactly that state;
  * push +/- e: the initial linear and angular velocities scaled by 1 + e and 1 - e (a push measured to within
    e; default 2 %);
  * another decomposition (--vhacd-resolution R, e.g. 100000): exactly that state, the same mesh decomposed by
    V-HACD at R voxels instead of the generator's (200,000): how much the final pose depends on the simulator's
    approximation of a concave mesh, which no cloud shows (procedural shapes with their own convex pieces and
    convex shapes are unchanged);
and the checkpoint's roll-outs (physdyn evaluate's) for reference. Over the recorded pushes that do not topple:
the final (60 steps, 4 s) position and rotation differences from the recording, median and p90.
Also, over all the test split's pushes that do not topple and keep spinning (|w_z| > 1 rad/s) for at least four
frames after the push: the spin's mean deceleration over those frames against the prior's mu g / r (r: the RMS
horizontal radius of the cloud, learn/prior.py) and against mu g e / k^2 (e: the mean horizontal distance of the
cloud's lowest points, within 1 mm, from the centre of mass; k^2: the cloud's mean squared horizontal distance
from it): the median ratio, the standard deviation of its log, and the correlation of the logs.
The spread between the recording and a replay or a 2 % different push is the part of the final pose that no
predictor reading the cloud and a measured push can be expected to recover.
Prints a table; the last line is one JSON object {n, replay: {pos_median_cm, pos_p90_cm, rot_median_deg,
rot_p90_deg}, push_plus: {...}, push_minus: {...}, model: {...}, speed_error, spin_decel: {n, prior: {ratio_median,
std_log, corr_log}, contact: {...}}}, with replay_vhacd: {...} and vhacd_resolution under --vhacd-resolution.
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
    from physdyn_ros import geometry as geo

    def pair(x: np.ndarray) -> tuple[float, float]:
        return round(float(np.median(x)), 2), round(float(np.percentile(x, 90)), 2)

    (pm, p9) = pair(np.linalg.norm(pos - true_pos, axis=1) * 100)
    (rm, r9) = pair(np.degrees(geo.quat_angle_between(quat, true_quat)))
    return {"pos_median_cm": pm, "pos_p90_cm": p9, "rot_median_deg": rm, "rot_p90_deg": r9}


def spin_deceleration(sims) -> dict:
    """The measured spin deceleration of the pushes that keep spinning against two readings of the cloud."""
    from physdyn_ros.conventions import GRAVITY
    from physdyn_ros.learn.baselines import horizontal_radius
    from physdyn_ros.learn.frames import pose_cloud

    rows = []
    for i in np.flatnonzero(sims.topple_index < 0):
        w = np.abs(sims.ang_vel[i, :, 2])
        k = 1
        while k + 1 < len(w) and w[k + 1] > 1.0:
            k += 1
        if k < 4 or w[1] <= w[k]:
            continue
        decel = (w[1] - w[k]) / ((k - 1) * sims.dt)
        p = pose_cloud(sims.points[sims.shape_index[i]], sims.scale[i], sims.quat[i, 0])  # origin at the COM
        xy, z = p[:, :2], p[:, 2]
        r_rms = float(horizontal_radius(p[None])[0])  # the prior's lever (learn/prior.py, baselines)
        lowest = z < z.min() + 0.001
        lever = np.mean(np.linalg.norm(xy[lowest], axis=1)) / np.mean(np.sum(xy ** 2, axis=1))
        mu_g = float(sims.friction[i]) * GRAVITY
        rows.append((decel, mu_g / r_rms, mu_g * lever))
    d = np.log(np.asarray(rows))
    out: dict = {"n": int(len(d))}
    for j, name in ((1, "prior"), (2, "contact")):
        ratio = d[:, 0] - d[:, j]
        out[name] = {"ratio_median": round(float(np.exp(np.median(ratio))), 3),
                     "std_log": round(float(np.std(ratio)), 3),
                     "corr_log": round(float(np.corrcoef(d[:, 0], d[:, j])[0, 1]), 3)}
    return out


def resimulate(sims, index: np.ndarray, shapes: list, factor: float,
               vhacd_resolution: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Final (HORIZON) positions and orientations of the pushes `index` re-simulated with their own shapes
    (`shapes`: the dataset's, in manifest order); vhacd_resolution > 0: concave meshes decomposed at that
    resolution instead of the generator's."""
    from physdyn_ros.sim import SimConfig, Simulator, simulate_from_state

    physics = dict(sims.manifest["generator"]["sim"])  # the generator's physics (decompositions are cached)
    if vhacd_resolution > 0:
        physics["vhacd_resolution"] = int(vhacd_resolution)
    config = SimConfig(**physics)
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
    ap.add_argument("--vhacd-resolution", type=int, default=0,
                    help="also replay with concave meshes decomposed at this V-HACD resolution (0: not)")
    args = ap.parse_args()
    if not 0.0 < args.speed_error < 0.5:
        raise SystemExit(f"--speed-error must be in (0, 0.5), got {args.speed_error}")
    if args.vhacd_resolution and not 10_000 <= args.vhacd_resolution <= 64_000_000:
        raise SystemExit(f"--vhacd-resolution must be 0 or in 10000..64000000 (V-HACD's range), got "
                         f"{args.vhacd_resolution}")
    import torch

    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import model_rollouts
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros.sim.generation.workers import build_shapes

    torch.set_num_threads(1)
    sims = load_sims(args.data, ["test"], categories=args.categories)
    index = np.arange(len(sims))
    if args.max_sequences < len(index):  # physdyn evaluate's choice of sequences
        index = np.linspace(0, len(sims) - 1, args.max_sequences).astype(np.int64)
    index = index[sims.topple_index[index] < 0]
    true_pos, true_quat = sims.pos[index, HORIZON], sims.quat[index, HORIZON]
    out: dict = {"n": int(len(index)), "speed_error": args.speed_error}
    t0 = time.perf_counter()
    shapes = build_shapes(sims.manifest["generator"])  # once: the procedural worlds hold thousands
    for name, factor in (("replay", 1.0), ("push_plus", 1.0 + args.speed_error),
                         ("push_minus", 1.0 - args.speed_error)):
        out[name] = final_errors(*resimulate(sims, index, shapes, factor), true_pos, true_quat)
    if args.vhacd_resolution:
        out["replay_vhacd"] = final_errors(*resimulate(sims, index, shapes, 1.0, args.vhacd_resolution), true_pos,
                                           true_quat)
        out["vhacd_resolution"] = args.vhacd_resolution
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
                        ("replay_vhacd", f"the same state, V-HACD at {args.vhacd_resolution} voxels"),
                        ("model", f"model {Path(args.checkpoint).name}")):
        if name not in out:
            continue
        e = out[name]
        print(f"| {label} | {e['pos_median_cm']} / {e['pos_p90_cm']} | {e['rot_median_deg']} / {e['rot_p90_deg']} |")
    out["spin_decel"] = spin_deceleration(sims)
    sd = out["spin_decel"]
    print(f"spin deceleration of the {sd['n']} test pushes that do not topple and keep spinning for 4+ frames: "
          + "; ".join(f"against {label}: median ratio {sd[k]['ratio_median']}, std of the log {sd[k]['std_log']}, "
                      f"correlation of the logs {sd[k]['corr_log']}"
                      for k, label in (("prior", "the prior's mu g / r"), ("contact", "mu g e / k^2 (lowest points)"))))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
