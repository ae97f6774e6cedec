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
"""Push planning on unseen shapes in pybullet: success of single pushes and of closed-loop re-planning.

    .venv/bin/python bench/bench_planning.py [--model PATH] [--trials 42] [--max-pushes 3] [--budget 0.2]
                                             [--skip-pybullet] [--skip-oracle] [--view 0|1]

Trials cycle through three groups of shapes no model was trained on:
  procedural: the paper's six categories and the trained families (physdyn_ros.shapes.families) at shape
              indices >= 9000 (training used 0-149);
  held_out:   the families kept out of training altogether (ring, dumbbell, legged);
  pybullet_data: the out-of-category meshes of pybullet_data.
Each trial spawns the object at a random yaw, draws a goal 8-22 cm away with a yaw change of up to +-45 deg,
and runs the closed loop (planning.closed_loop.push_to_goal: plan, push in pybullet with the impulse at the
planned contact point and the true mass, observe, adapt, re-plan) for up to --max-pushes pushes. Success =
within 2 cm and 10 deg of the goal, upright; the yaw taken modulo the symmetry of the first observed cloud
about its up axis (planning.symmetry: an upright cylinder's yaw is not checked, a square box's modulo 90 deg),
the rule the planner plans with. Every trial ends with an outcome (planning.session.OUTCOMES):
reached, refused, toppled, out_of_pushes. Every planned contact point is checked against the true mesh: its
distance to the object's surface (posed at the push) is reported (max, mm).
The same trials are run with
  learned:  the planner over the learned model (the shipped one unless --model);
  oracle:   the same planner over the true simulator (planning.sim_model.ExactSimModel: the world itself,
            restored per candidate; no tipping estimate, pybullet decides topples) with a
            fixed search (--oracle-iterations CEM iterations of 48 candidates: re-simulation is slow, the
            ceiling must not depend on it): what the task allows;
  pybullet: the planner over pybullet re-simulation of the cloud's convex hull with friction off by +20 %
            (what a robotics user would plan with instead of a learned model).
Unpushable trials: those the oracle cannot do upright, i.e. its episode ends refused (no push of the search
keeps the object upright under the perturbations) or toppled. unpushable_refused counts those the learned
planner refused; the goals are quoted against the oracle (success / oracle success).
Prints a table per planner and per group; the last line is one JSON object (success_1push, success_3push,
oracle_success_1push, oracle_success_3push, toppled_fraction, unpushable_trials, unpushable_refused,
plan_time_p50_s, trials, ...).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PAPER = ["box", "cylinder", "bottle", "mug", "trashcan", "speaker"]
TRAINED_FAMILIES = ["superellipsoid", "capsule", "prism", "pyramid", "wedge", "polyhedron", "rock", "vase",
                    "letter", "stack", "composite", "gear"]
HELD_OUT = ["ring", "dumbbell", "legged"]
GROUPS = ("procedural", "held_out", "pybullet_data")
#: --view: one depth camera per trial, this far above the table plane (rad; the suite's sim camera looks down 29
#: deg), at an azimuth of its own, with Gaussian noise of this std (m) on the points.
VIEW_ELEVATION = math.radians(30.0)
VIEW_NOISE = 0.002


def trials(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        group = GROUPS[i % len(GROUPS)]
        k = i // len(GROUPS)
        if group == "procedural":
            pool = PAPER + TRAINED_FAMILIES
            cat, shape_seed = pool[k % len(pool)], 9000 + k
        elif group == "held_out":
            cat, shape_seed = HELD_OUT[k % len(HELD_OUT)], 9000 + k
        else:
            cat, shape_seed = "pybullet_data", k
        yaw0 = float(rng.uniform(-math.pi, math.pi))
        d, bearing = float(rng.uniform(0.08, 0.22)), float(rng.uniform(-math.pi, math.pi))
        # the camera of --view: its own stream, so the trials are the same with and without it
        az = float(np.random.default_rng([seed, i]).uniform(-math.pi, math.pi))
        out.append({"group": group, "category": cat, "shape_seed": shape_seed, "yaw0": yaw0,
                    "goal": (d * math.cos(bearing), d * math.sin(bearing),
                             yaw0 + float(rng.uniform(-math.pi / 4, math.pi / 4))),
                    "camera": (math.cos(VIEW_ELEVATION) * math.cos(az), math.cos(VIEW_ELEVATION) * math.sin(az),
                               math.sin(VIEW_ELEVATION)), "noise_seed": (seed, i)})
    return out


def surface_distance(sim, point: np.ndarray, pose_pos: np.ndarray, pose_quat: np.ndarray) -> float:
    """m from `point` (table frame) to the true mesh of the simulator's object posed at (pos, quat)."""
    from scipy.spatial.transform import Rotation

    from physdyn_ros.shapes.core import surface_distance as mesh_distance

    local = Rotation.from_quat(pose_quat).inv().apply(np.asarray(point) - pose_pos)
    return float(mesh_distance(np.asarray(sim.shape.vertices) * np.asarray(sim.scale), sim.shape.faces, local)[0])


def run(model, name: str, cases: list[dict], max_pushes: int, budget: float, friction: float,
        max_topple: float, robust: int = 6, adapt: bool = True, iterations: int = 0, risk: dict | None = None,
        ensemble: tuple = (), view: bool = False) -> dict:
    """The closed loop over every case; `model` a DynamicsModel, or "oracle" for the true simulator; `ensemble`:
    further members for the learned planner's robustness check; `view`: the planner sees each trial's camera's
    view with VIEW_NOISE."""
    from physdyn_ros.planning import Goal, PlannerConfig, Pose2D, PushPlanner
    from physdyn_ros.planning import closed_loop
    from physdyn_ros.planning.sim_model import ExactSimModel, PybulletModel
    from physdyn_ros.shapes import resolve_shape
    from physdyn_ros.sim import SimConfig, Simulator

    cfg = PlannerConfig(time_budget=budget, max_topple_probability=max_topple, robust_candidates=robust)
    if iterations:  # a fixed search, independent of the machine's load (for comparing planner variants)
        cfg = PlannerConfig(time_budget=60.0, samples=48, max_iterations=iterations,
                            max_topple_probability=max_topple, robust_candidates=robust)
    cfg = replace(cfg, **(risk or {}))
    rows, times, contact_mm = [], [], []
    t0 = time.monotonic()
    with Simulator(SimConfig(friction=friction, collision="parts")) as sim:
        oracle = model == "oracle"
        if oracle:  # the world itself decides topples: no tipping estimate
            model, cfg = ExactSimModel(sim), replace(cfg, tip_check=False, physics_check=False)
        elif isinstance(model, PybulletModel):
            cfg = replace(cfg, physics_check=False)  # a planner over hull physics checks nothing twice
        planner = PushPlanner(model, cfg, ensemble=ensemble)
        if not oracle:  # the oracle's model reads the simulator's object: there is none before the first trial
            planner.warm_up()
        original = closed_loop.execute

        def execute(sim_, plan, mode="impulse", num_frames=76):  # measure every contact against the true mesh
            pos, quat, _, _ = sim_.state()
            contact_mm.append(1e3 * surface_distance(sim_, plan.contact_point, pos, quat))
            if contact_mm[-1] > 2.0:
                print(f"    contact {contact_mm[-1]:.1f} mm off the surface of {sim_.shape.name}", flush=True)
            return original(sim_, plan, mode, num_frames)

        closed_loop.execute = execute
        try:
            for c in cases:
                shape, sim_ok = None, False
                for extra in range(5):  # a mesh that cannot stand upright is not a pushing trial: take the next
                    step = 1 if c["category"] == "pybullet_data" else 1000
                    shape = resolve_shape(c["category"], c["shape_seed"] + step * extra)
                    sim.spawn(shape, xy=(0.0, 0.0), yaw=c["yaw0"])
                    sim_ok = not closed_loop.observe(sim).toppled
                    if sim_ok:
                        break
                goal = Goal(Pose2D(*c["goal"]), 0.02, math.radians(10.0))
                seen = {"view": np.array(c["camera"]), "cloud_noise": VIEW_NOISE,
                        "rng": np.random.default_rng(c["noise_seed"])} if view else {}
                res = closed_loop.push_to_goal(sim, planner, goal, max_pushes=max_pushes, mass=sim.mass, adapt=adapt,
                                               **seen)
                times += res.planning_times
                p1 = res.pushes[0] if res.pushes else None
                first = bool(p1 and not p1.toppled and p1.position_error <= 0.02
                             and p1.yaw_error <= math.radians(10.0))
                rows.append({"group": c["group"], "first": first, "final": bool(res.success),
                             "p_success": float(p1.plan.success_probability) if p1 else math.nan,
                             "outcome": res.outcome, "pushes": len(res.pushes), "shape": shape.name,
                             "yaw_symmetry": res.goal.yaw_symmetry if res.goal else None})
                e1 = (f"{100 * p1.position_error:4.1f} cm {math.degrees(p1.yaw_error):5.1f} deg (predicted "
                      f"{100 * p1.plan.position_error:.1f} cm, {math.degrees(p1.plan.yaw_error):.1f} deg)"
                      if p1 else "-")
                print(f"  [{name}] {c['group']:<13} {shape.name:<28} 1 push: {'ok ' if first else 'no '} {e1:<46} "
                      f"{res.outcome:<13} after {len(res.pushes)}: {res.message}", flush=True)
        finally:
            closed_loop.execute = original
            planner.close()
            if oracle:
                model.close()
    t = np.array(times) if times else np.array([math.nan])
    outcomes = Counter(r["outcome"] for r in rows)
    groups = {g: {"trials": sum(r["group"] == g for r in rows),
                  "success_1push": float(np.mean([r["first"] for r in rows if r["group"] == g] or [math.nan])),
                  "success_3push": float(np.mean([r["final"] for r in rows if r["group"] == g] or [math.nan]))}
              for g in GROUPS}
    return {"name": name, "n": len(cases), "rows": rows, "first": float(np.mean([r["first"] for r in rows])),
            "final": float(np.mean([r["final"] for r in rows])), "plan_p50": float(np.median(t)),
            "plan_p90": float(np.percentile(t, 90)), "outcomes": dict(outcomes), "groups": groups,
            "contact_max_mm": float(max(contact_mm, default=math.nan)),
            "contact_p50_mm": float(np.median(contact_mm)) if contact_mm else math.nan,
            "seconds": time.monotonic() - t0}


#: Oracle outcomes that make a trial unpushable: no push of the oracle's search keeps the object upright (under
#: the planner's perturbations), or the one it chose toppled it.
UNPUSHABLE = ("refused", "toppled")


def success_bins(rows: list[dict]) -> list[dict]:
    """The first pushes by their plan's success_probability (quarters of [0, 1]): how many, their
    mean estimate and the share that succeeded (empty where the plans carry no estimate)."""
    pairs = [(r["p_success"], r["first"]) for r in rows if math.isfinite(r.get("p_success", math.nan))]
    out = []
    for lo, hi in ((0.0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.01)):
        sel = [(p, ok) for p, ok in pairs if lo <= p < hi]
        out.append({"bin": f"{lo:g}-{min(hi, 1.0):g}", "n": len(sel),
                    "estimate": round(float(np.mean([p for p, _ in sel])), 3) if sel else None,
                    "observed": round(float(np.mean([ok for _, ok in sel])), 3) if sel else None})
    return out if pairs else []


def ceiling_figures(learned: dict, oracle: dict | None) -> dict:
    """The JSON line's figures against the oracle (None values without one)."""
    if oracle is None:
        return {"oracle_success_1push": None, "oracle_success_3push": None, "of_oracle_1push": None,
                "of_oracle_3push": None, "unpushable_trials": None, "unpushable_refused": None}
    pairs = list(zip(learned["rows"], oracle["rows"]))
    unpushable = [a for a, b in pairs if b["outcome"] in UNPUSHABLE]

    def share(key: str) -> float | None:
        ok = sum(b[key] for _, b in pairs)
        return round(sum(a[key] for a, _ in pairs) / ok, 3) if ok else None

    return {"oracle_success_1push": round(oracle["first"], 3), "oracle_success_3push": round(oracle["final"], 3),
            "of_oracle_1push": share("first"), "of_oracle_3push": share("final"),
            "unpushable_trials": len(unpushable),
            "unpushable_refused": sum(a["outcome"] == "refused" for a in unpushable)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    ap.add_argument("--trials", type=int, default=42)
    ap.add_argument("--max-pushes", type=int, default=3)
    ap.add_argument("--budget", type=float, default=0.2, help="planning time budget per push, s")
    ap.add_argument("--friction", type=float, default=0.5, help="true friction of the simulated table")
    ap.add_argument("--friction-error", type=float, default=0.2, help="pybullet planner: relative friction error")
    ap.add_argument("--max-topple", type=float, default=0.35, help="planner max_topple_probability")
    ap.add_argument("--pessimistic", type=int, choices=(0, 1), default=None,
                    help="planner pessimistic: 1 holds the worst perturbed push to the limit (default: its own)")
    ap.add_argument("--physics-check", type=int, choices=(0, 1), default=1,
                    help="learned planner physics_check: re-simulate its finalists on the cloud's hull (default 1)")
    ap.add_argument("--whole-cloud", type=int, choices=(0, 1), default=1,
                    help="planner whole_cloud: 1 the physics check weighs the solid the cloud encloses, 0 its hull")
    ap.add_argument("--view", type=int, choices=(0, 1), default=0,
                    help="1: the learned planner sees one depth camera's view per trial (30 deg up, 2 mm noise) and "
                         "plans with whole_cloud false; the oracle keeps the whole cloud")
    ap.add_argument("--physics-fusion", type=int, choices=(0, 1), default=1,
                    help="planner physics_fusion: 1 the physics check's verdict is the model's topple fusion "
                         "(whole clouds, a checkpoint with fusion weights), 0 the share of toppled runs")
    ap.add_argument("--skip-pybullet", action="store_true", help="no planner over the cloud's hull in pybullet")
    ap.add_argument("--skip-oracle", action="store_true", help="no planner over the true simulator (the ceiling)")
    ap.add_argument("--oracle-iterations", type=int, default=3,
                    help="the oracle's fixed search: CEM iterations of 48 candidates (0: the --budget)")
    ap.add_argument("--robust-candidates", type=int, default=6, help="planner robust_candidates (0: no check)")
    ap.add_argument("--no-adapt", action="store_true", help="do not aim pushes by the observed slide ratio")
    ap.add_argument("--iterations", type=int, default=0,
                    help="fixed search (48 samples x N CEM iterations, no time budget) to compare variants")
    ap.add_argument("--ensemble", type=int, default=0,
                    help="models in the learned planner's robustness check, the shipped model and the shipped "
                         "members (models/ensemble-*.pt); 0 (default, as plan_push): every shipped member; 1: the "
                         "model alone")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import torch

    from physdyn_ros.planning.sim_model import PybulletModel
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import ensemble_paths

    torch.set_num_threads(args.threads)
    cases = trials(args.trials, args.seed)
    risk = {} if args.pessimistic is None else {"pessimistic": bool(args.pessimistic)}
    risk["physics_check"] = bool(args.physics_check)
    risk["whole_cloud"] = bool(args.whole_cloud) and not args.view
    risk["physics_fusion"] = bool(args.physics_fusion)
    try:
        members = ensemble_paths(args.ensemble, args.model or "")
    except ValueError as exc:
        sys.exit(f"bench_planning: --ensemble: {exc}")
    ensemble = tuple(Predictor.load(m, threads=args.threads) for m in members)
    results = [run(Predictor.load(args.model, threads=args.threads), "learned", cases, args.max_pushes, args.budget,
                   args.friction, args.max_topple, args.robust_candidates, not args.no_adapt, args.iterations, risk,
                   ensemble, bool(args.view))]
    oracle = None
    if not args.skip_oracle:
        oracle = run("oracle", "oracle (true simulator)", cases, args.max_pushes, args.budget, args.friction,
                     args.max_topple, args.robust_candidates, not args.no_adapt, args.oracle_iterations, risk)
        results.append(oracle)
    if not args.skip_pybullet:
        with PybulletModel(friction=args.friction * (1 + args.friction_error)) as pb:
            results.append(run(pb, f"pybullet hull, mu +{100 * args.friction_error:.0f}%", cases, args.max_pushes,
                               args.budget, args.friction, args.max_topple, args.robust_candidates,
                               not args.no_adapt, args.iterations, risk))
    print(f"\n{args.trials} trials (goal 8-22 cm away, yaw change up to 45 deg; success: within 2 cm and 10 deg, "
          f"upright); planning budget {args.budget} s per push, {args.threads} thread(s)")
    print(f"| planner model | success, 1 push | success, <= {args.max_pushes} pushes | planning time per push "
          "p50 / p90 (s) | reached / refused / toppled / out of pushes | contact to surface max (mm) |")
    print("|---|---|---|---|---|---|")
    for r in results:
        o = r["outcomes"]
        print(f"| {r['name']} | {100 * r['first']:.0f}% | {100 * r['final']:.0f}% | {r['plan_p50']:.3f} / "
              f"{r['plan_p90']:.3f} | {o.get('reached', 0)} / {o.get('refused', 0)} / {o.get('toppled', 0)} / "
              f"{o.get('out_of_pushes', 0)} | {r['contact_max_mm']:.2f} |")
    print("\n| planner model | group | trials | success, 1 push | success, <= 3 pushes |\n|---|---|---|---|---|")
    for r in results:
        for g, v in r["groups"].items():
            print(f"| {r['name']} | {g} | {v['trials']} | {100 * v['success_1push']:.0f}% | "
                  f"{100 * v['success_3push']:.0f}% |")
    learned = results[0]
    hull = next((r for r in results[1:] if r is not oracle), None)
    ceiling = ceiling_figures(learned, oracle)
    print(f"\nyaw checked modulo a symmetry in {sum(r['yaw_symmetry'] not in (None, 1) for r in learned['rows'])} "
          f"trials (ignored in {sum(r['yaw_symmetry'] == 0 for r in learned['rows'])})")
    if oracle is not None:
        print(f"against the oracle: {ceiling['of_oracle_1push']} of its 1-push and {ceiling['of_oracle_3push']} of its "
              f"<= {args.max_pushes}-push successes; {ceiling['unpushable_trials']} unpushable trials (the oracle "
              f"refused or toppled), {ceiling['unpushable_refused']} of them refused by the learned planner")
        for i, (a, b) in enumerate(zip(learned["rows"], oracle["rows"])):
            if b["outcome"] in UNPUSHABLE or a["final"] != b["final"]:
                print(f"  trial {i:2d} {a['shape']:<28} learned {a['outcome']:<13} oracle {b['outcome']}")
    bins = success_bins(learned["rows"])
    if bins:
        print("first push's success_probability (the plan's estimate) against its outcome: " + ", ".join(
            f"{b['bin']}: {b['n']} pushes, mean estimate {b['estimate']:.2f}, {100 * b['observed']:.0f} % succeeded"
            for b in bins if b["n"]))
    out = {"trials": args.trials, "success_1push": round(learned["first"], 3),
           "success_3push": round(learned["final"], 3), **ceiling,
           "toppled_fraction": round(learned["outcomes"].get("toppled", 0) / max(len(learned["rows"]), 1), 3),
           "plan_time_p50_s": round(learned["plan_p50"], 4),
           "plan_time_p90_s": round(learned["plan_p90"], 4), "reached": learned["outcomes"].get("reached", 0),
           "refused": learned["outcomes"].get("refused", 0), "toppled": learned["outcomes"].get("toppled", 0),
           "out_of_pushes": learned["outcomes"].get("out_of_pushes", 0),
           "contact_surface_max_mm": round(learned["contact_max_mm"], 3),
           "groups": {g: {k: round(v, 3) for k, v in d.items()} for g, d in learned["groups"].items()},
           "pessimistic": bool(risk.get("pessimistic", False)), "whole_cloud": bool(risk["whole_cloud"]),
           "view": bool(args.view),
           "physics_fusion": bool(risk["physics_fusion"]), "ensemble": 1 + len(ensemble),
           "yaw_symmetric_trials": sum(r["yaw_symmetry"] not in (None, 1) for r in learned["rows"]),
           "pybullet_success_1push": round(hull["first"], 3) if hull else None,
           "pybullet_success_3push": round(hull["final"], 3) if hull else None,
           "pybullet_plan_time_p50_s": round(hull["plan_p50"], 4) if hull else None,
           "success_estimate_bins": bins}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
