#!/usr/bin/env python3
"""Push planning on unseen shapes in pybullet: success of single pushes and of closed-loop re-planning.

    .venv/bin/python bench/bench_planning.py [--model PATH] [--trials 36] [--max-pushes 3] [--budget 0.5]

Each trial spawns an unseen object (procedural shapes with indices never generated for training, and the
out-of-category pybullet_data meshes) at a random yaw, draws a goal 8-22 cm away with a yaw change of up to
+-45 deg, and asks the planner for a push; the push is executed in pybullet (impulse at the planned contact
point, the simulator's true mass) and re-planned from where the object stopped, up to --max-pushes pushes.
Success = within 2 cm and 10 deg of the goal, upright. The same trials are run with
  learned:  the planner over the learned model (the shipped one unless --model);
  pybullet: the planner over pybullet re-simulation of the cloud's convex hull with friction off by +20 %
            (what a robotics user would plan with instead of a learned model).
Prints success after 1 push and after --max-pushes, planning time per push (p50 / p90), per source.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def trials(n: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    cats = ["box", "cylinder", "bottle", "mug", "trashcan", "speaker", "pybullet_data"]
    out = []
    for i in range(n):
        cat = cats[i % len(cats)]
        yaw0 = float(rng.uniform(-math.pi, math.pi))
        d, bearing = float(rng.uniform(0.08, 0.22)), float(rng.uniform(-math.pi, math.pi))
        out.append({"category": cat, "shape_seed": (9000 + i) if cat != "pybullet_data" else i // len(cats),
                    "yaw0": yaw0, "goal": (d * math.cos(bearing), d * math.sin(bearing),
                                           yaw0 + float(rng.uniform(-math.pi / 4, math.pi / 4)))})
    return out


def run(model, name: str, cases: list[dict], max_pushes: int, budget: float, friction: float,
        max_topple: float = 0.2) -> dict:
    from physdyn_ros.planning import Goal, PlannerConfig, Pose2D, PushPlanner
    from physdyn_ros.planning.closed_loop import push_to_goal
    from physdyn_ros.shapes import resolve_shape
    from physdyn_ros.sim import SimConfig, Simulator

    planner = PushPlanner(model, PlannerConfig(time_budget=budget, max_topple_probability=max_topple))
    planner.warm_up()
    first, final, times, toppled, refused = [], [], [], 0, 0
    t0 = time.monotonic()
    with Simulator(SimConfig(friction=friction)) as sim:
        for c in cases:
            shape = resolve_shape(c["category"], c["shape_seed"])
            sim.spawn(shape, xy=(0.0, 0.0), yaw=c["yaw0"])
            goal = Goal(Pose2D(*c["goal"]), 0.02, math.radians(10.0))
            res = push_to_goal(sim, planner, goal, max_pushes=max_pushes, mass=sim.mass)
            times += res.planning_times
            refused += int(not res.pushes or (len(res.pushes) < max_pushes and not res.success
                                                and "toppled" not in res.message))
            toppled += int(any(p.toppled for p in res.pushes))
            p1 = res.pushes[0] if res.pushes else None
            first.append(bool(p1 and not p1.toppled and p1.position_error <= 0.02
                              and p1.yaw_error <= math.radians(10.0)))
            final.append(bool(res.success))
            print(f"  [{name}] {shape.name:<28} 1 push: {'ok ' if first[-1] else 'no '} "
                  f"after {len(res.pushes)}: {'ok ' if res.success else 'no '} {res.message}", flush=True)
    t = np.array(times) if times else np.array([math.nan])
    return {"name": name, "n": len(cases), "first": float(np.mean(first)), "final": float(np.mean(final)),
            "plan_p50": float(np.median(t)), "plan_p90": float(np.percentile(t, 90)), "toppled": toppled,
            "refused": refused, "seconds": time.monotonic() - t0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    ap.add_argument("--trials", type=int, default=35)
    ap.add_argument("--max-pushes", type=int, default=3)
    ap.add_argument("--budget", type=float, default=0.5, help="planning time budget per push, s")
    ap.add_argument("--friction", type=float, default=0.5, help="true friction of the simulated table")
    ap.add_argument("--friction-error", type=float, default=0.2, help="pybullet planner: relative friction error")
    ap.add_argument("--max-topple", type=float, default=0.2, help="planner max_topple_probability")
    ap.add_argument("--skip-pybullet", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import torch

    from physdyn_ros.planning.sim_model import PybulletModel
    from physdyn_ros.predictor import Predictor

    torch.set_num_threads(args.threads)
    cases = trials(args.trials, args.seed)
    results = [run(Predictor.load(args.model, threads=args.threads), "learned", cases, args.max_pushes, args.budget,
                   args.friction, args.max_topple)]
    if not args.skip_pybullet:
        with PybulletModel(friction=args.friction * (1 + args.friction_error)) as pb:
            results.append(run(pb, f"pybullet hull, mu +{100 * args.friction_error:.0f}%", cases, args.max_pushes,
                               args.budget, args.friction, args.max_topple))
    print(f"\n{args.trials} trials (goal 8-22 cm away, yaw change up to 45 deg; success: within 2 cm and 10 deg, "
          f"upright); planning budget {args.budget} s per push, {args.threads} thread(s)")
    print(f"| planner model | success, 1 push | success, <= {args.max_pushes} pushes | planning time per push "
          "p50 / p90 (s) | trials with a topple | stopped by a refusal |")
    print("|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['name']} | {100 * r['first']:.0f}% | {100 * r['final']:.0f}% | {r['plan_p50']:.3f} / "
              f"{r['plan_p90']:.3f} | {r['toppled']} | {r['refused']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
