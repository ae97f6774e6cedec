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
"""Whole-push topple decisions: the model, pybullet on the cloud's hull and solid, and their fusion.

    .venv/bin/python bench/topple_mix.py [--data data/heldout_families] [--max-sequences 800] [--partial 0]
        [--checkpoint physdyn_ros/models/default.pt] [--exact-runs 0]

On the same test pushes: the model's whole-push topple probability (its 60-step roll-out's highest, as `physdyn
evaluate` scores it; --partial 1: from one camera's view with 2 mm noise), pybullet re-simulating the cloud's convex
hull (whole cloud, true initial state) at the true friction -20 % and +20 % (toppled or not), and mixtures fixed in
advance: the mean of the model and the two hull runs, and 0.6 x the model + 0.4 x the hulls' mean. With whole
clouds also the hull weighing as the solid the cloud encloses (topple_fusion.SolidPhysics, about the solid's own
centre of mass) at -20 % and +20 %, and the checkpoint's topple fusion (physdyn_ros.topple_fusion: the model and
those runs, weights fitted on other shapes and stored beside the checkpoint). With `--partial 1` also pybullet on
the convex hull of each view the model saw (what the planner's physics check simulates with whole_cloud false),
-20 % and +20 %. `--exact-runs K`: the ceiling of any predictor fed these initial states, the true shape (the
dataset's procedural shapes, rebuilt) re-simulated K times with the initial velocities perturbed by 1 % (pushing is
chaotic near the topple boundary: a re-run does not always repeat the recorded outcome); its topple probability is
the share of toppled runs.
Prints F1 (precision / recall) at 0.5 and the Brier score of each, and the reliability of the model's and the
fusion's probabilities in five bins (pushes, mean predicted, observed topple frequency); the last line is one JSON
object {method: {f1, precision, recall, brier[, reliability]}, "pushes": n, "topples": k}.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ROLLOUT_BATCH = 256  # the model's roll-outs per batch; each batch draws its views from its own seed
VIEW_NOISE = 0.002  # m of Gaussian noise on one camera's views (--partial)


def scores(prob: np.ndarray, truth: np.ndarray) -> dict:
    from physdyn_ros.learn.evaluate import topple_scores

    s = topple_scores(prob >= 0.5, truth > 0.5)  # None where undefined: 0 here
    return {**{k: round(s[k] or 0.0, 3) for k in ("f1", "precision", "recall")},
            "brier": round(float(np.mean((prob - (truth > 0.5)) ** 2)), 4)}


def exact_topples(sims, index: np.ndarray, runs: int, horizon: int, noise: float = 0.01) -> np.ndarray:
    """Share of `runs` re-simulations of the true shape that topple, the initial velocities scaled by 1 + N(0,
    noise) each (the dataset's procedural shapes, rebuilt from their ids, at their scale, yaw and friction)."""
    from scipy.spatial.transform import Rotation

    from physdyn_ros.data import Dataset
    from physdyn_ros.learn.baselines import sim_config_from_manifest
    from physdyn_ros.shapes.procedural import make_procedural
    from physdyn_ros.sim import SimConfig, Simulator
    from physdyn_ros.sim.push import record

    ds = Dataset(sims.root)
    ids = {int(s["index"]): s["id"] for s in ds.shapes}
    cfg = replace(sim_config_from_manifest(sims.manifest), collision=SimConfig().collision)
    rng = np.random.default_rng(0)
    out = np.zeros(len(index))
    with Simulator(cfg) as sim:
        for j, i in enumerate(index):
            category, number = ids[int(sims.shape_index[i])].rsplit("_", 1)
            shape = make_procedural(category, int(number), int(ds.manifest.get("seed", 0)))
            yaw = float(Rotation.from_quat(sims.quat[i, 0].astype(np.float64)).as_euler("ZYX")[0])
            for _ in range(runs):
                sim.spawn(shape, sims.scale[i].astype(np.float64), xy=sims.pos[i, 0, :2], yaw=yaw,
                          friction=float(sims.friction[i]))
                sim.set_velocity(sims.lin_vel[i, 0] * (1 + noise * rng.standard_normal()),
                                 sims.ang_vel[i, 0] * (1 + noise * rng.standard_normal()))
                out[j] += float(record(sim, horizon + 1)["toppled"].max()) / runs
    return out


def view_verdicts(sims, index: np.ndarray, horizon: int, friction_error: float, num_points: int,
                  noise: float) -> dict[str, np.ndarray]:
    """pybullet on the convex hull of one camera's view of each push at uniform density (what the planner checks
    with whole_cloud false): the views model_rollouts(partial=1, noise) drew for a model of `num_points` points
    (its batches and view seeds), the true initial velocities about the true centre of mass, friction -/+
    friction_error. (B,) 1.0 where it toppled, per sign."""
    from physdyn_ros.learn.baselines import pybullet_resimulate
    from physdyn_ros.learn.evaluate import _batches
    from physdyn_ros.learn.support import DESCRIPTOR_POINTS
    from physdyn_ros.learn.windows import sequences
    from physdyn_ros.shapes.core import shape_from_points

    views, coms, lin = [], [], []
    ang = np.zeros((len(index), 3))
    for sl in _batches(len(index), ROLLOUT_BATCH):  # model_rollouts' batches and view seeds: the model's views
        seq = sequences(sims, horizon, num_points, index[sl], 1.0, noise, view_seed=sl.start,
                        desc_points=DESCRIPTOR_POINTS)
        lift = np.zeros((sl.stop - sl.start, 3))
        lift[:, 2] = -seq["table"].double().numpy()  # frame C with the table at z = 0
        ang[sl] = seq["angvel"][:, 0].double().numpy()
        for view, com, v0, w0 in zip(seq["desc_cloud"].double().numpy() + lift[:, None],
                                     seq["com"].double().numpy() + lift, seq["vel"][:, 0].double().numpy(), ang[sl]):
            c = shape_from_points(view).mass_properties().com  # the hull's own centre of mass is its body's origin
            views.append(view - c)
            coms.append(c)
            lin.append(v0 + np.cross(w0, c - com))
    n = len(index)
    state = (np.ones((n, 3)), np.array(coms), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.array(lin), ang)
    return {sign: pybullet_resimulate(np.stack(views), *state, sims.friction[index] * (1.0 + f * friction_error),
                                      horizon, sims.manifest)["toppled"].max(axis=1).astype(np.float64)
            for sign, f in (("-", -1.0), ("+", 1.0))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default=None, help="default: the shipped model")
    ap.add_argument("--data", default="data/heldout_families")
    ap.add_argument("--max-sequences", type=int, default=800)
    ap.add_argument("--partial", type=float, default=0.0, help="share of the model's clouds seen by one camera")
    ap.add_argument("--friction-error", type=float, default=0.2)
    ap.add_argument("--exact-runs", type=int, default=0, help="re-simulate the true shapes this many times (0: no)")
    args = ap.parse_args()

    import torch

    from physdyn_ros.learn.baselines import pybullet_resimulate
    from physdyn_ros.learn.checkpoint import load_model
    from physdyn_ros.learn.evaluate import calibration, ground_truth, model_rollouts
    from physdyn_ros.learn.windows import load_sims
    from physdyn_ros import topple_fusion
    from physdyn_ros.resources import DEFAULT_MODEL
    from physdyn_ros.topple_fusion_fit import push_verdicts

    torch.set_num_threads(1)
    ckpt = args.checkpoint or DEFAULT_MODEL
    model, _ = load_model(ckpt)
    sims = load_sims(args.data, ["test"])
    index = np.linspace(0, len(sims) - 1, min(args.max_sequences, len(sims))).astype(np.int64)
    horizon = 60
    with torch.inference_mode():
        rolled = model_rollouts(model, sims, index, horizon, batch_size=ROLLOUT_BATCH, partial=args.partial,
                                noise=VIEW_NOISE if args.partial else 0.0)
    truth = ground_truth(sims, index, horizon).topple_prob.max(axis=1)
    p_model = rolled.topple_prob.max(axis=1)
    pts = sims.points[sims.shape_index[index]]
    state0 = (sims.pos[index, 0], sims.quat[index, 0], sims.lin_vel[index, 0], sims.ang_vel[index, 0])
    hull = {}
    for sign, name in ((-1, "minus"), (1, "plus")):
        mu = sims.friction[index] * (1.0 + sign * args.friction_error)
        hull[name] = pybullet_resimulate(pts, sims.scale[index], *state0, mu, horizon,
                                         sims.manifest)["toppled"].max(axis=1).astype(np.float64)
    hull_mean = 0.5 * (hull["minus"] + hull["plus"])
    pct = int(round(100 * args.friction_error))
    methods = {"model": p_model, f"pybullet hull mu -{pct}%": hull["minus"], f"pybullet hull mu +{pct}%": hull["plus"],
               "mean of model and both hulls": (p_model + hull["minus"] + hull["plus"]) / 3.0,
               "0.6 model + 0.4 hulls' mean": 0.6 * p_model + 0.4 * hull_mean}
    fusion_path = topple_fusion.fusion_path(ckpt)
    if not args.partial:  # the solid needs the whole cloud
        solid = push_verdicts(sims, index)  # topple_fusion.RUNS: as given, friction -20 % / +20 %, speed -/+10 %
        lower, higher = (round(100 * abs(1.0 - f)) for f, _ in topple_fusion.RUNS[1:3])
        methods.update({f"pybullet solid mu -{lower}%": solid[:, 1], f"pybullet solid mu +{higher}%": solid[:, 2]})
        if fusion_path.is_file():
            weights = topple_fusion.FusionWeights.load(fusion_path)
            methods["fusion (model + solid physics)"] = weights.fuse(p_model, solid)
    if args.partial >= 1.0:  # every cloud a view: pybullet on the view's hull
        seen = view_verdicts(sims, index, horizon, args.friction_error, model.cfg.num_points, VIEW_NOISE)
        methods.update({f"pybullet view hull mu {sign}{pct}%": seen[sign] for sign in "-+"})
    if args.exact_runs > 0:
        methods[f"true shape, {args.exact_runs} runs (ceiling)"] = exact_topples(sims, index, args.exact_runs, horizon)
    result: dict = {name: scores(p, truth) for name, p in methods.items()}
    shown = [m for m in ("model", "fusion (model + solid physics)") if m in methods]
    for name in shown:  # reliability: is a predicted 0.3 a topple in 3 of 10?
        result[name]["reliability"] = calibration(methods[name], truth, bins=5)["reliability"]
    view = "one camera's view" if args.partial else "whole clouds"
    print(f"{args.data}: {len(index)} pushes, {int(truth.sum())} topples, {view}")
    print(f"{'method':<32} {'F1 (P / R)':>20} {'Brier':>7}")
    for name, r in result.items():
        print(f"{name:<32} {r['f1']:>8.3f} ({r['precision']:.2f} / {r['recall']:.2f}) {r['brier']:>7.4f}")
    for name in shown:
        print(f"reliability of {name}: " + ", ".join(
            f"{r['bin']}: {r['n']} pushes, predicted {r['predicted']:.2f}, observed {r['observed']:.2f}"
            for r in result[name]["reliability"] if r["n"]))
    result.update(pushes=int(len(index)), topples=int(truth.sum()))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
