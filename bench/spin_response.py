#!/usr/bin/env python3
"""How well a model follows the spin of a pushed object that slides while it turns (issue 11 / 16).

    .venv/bin/python bench/spin_response.py [--model PATH] [--trials 24]

For the first --trials trials of bench/bench_planning.py (the same shapes, start yaws and goals), the planner over
the model plans the first push, pybullet executes it (the impulse at the planned contact point, the true mass),
and the spin about the vertical is compared: right after the impulse (the planner's rigid-body estimate against
pybullet's response), after one step of 1/15 s (the model's prediction against pybullet), and the turn at rest
(predicted against real). Prints one line per trial; the last line is one JSON object: trials,
impulse_spin_ratio_median (planned / real w_z right after the push), step1_spin_ratio_median (model / real w_z
after one step), turn_ratio_median (real / predicted turn at rest), over pushes with |w_z| >= 1 rad/s.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    ap.add_argument("--trials", type=int, default=24)
    ap.add_argument("--budget", type=float, default=0.2, help="planning time budget per push, s")
    args = ap.parse_args()

    import torch
    from bench_planning import trials

    from physdyn_ros.planning import Goal, PlannerConfig, PlanningError, Pose2D, PushPlanner, closed_loop, wrap_angle
    from physdyn_ros.planning.planner import yaw_of
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.shapes import resolve_shape
    from physdyn_ros.sim import SimConfig, Simulator

    torch.set_num_threads(1)
    pred = Predictor.load(args.model, threads=1)
    planner = PushPlanner(pred, PlannerConfig(time_budget=args.budget))
    planner.warm_up()
    rows = []
    with Simulator(SimConfig(friction=0.5, collision="parts")) as sim:
        for c in trials(args.trials, 0):
            shape = resolve_shape(c["category"], c["shape_seed"])
            sim.spawn(shape, xy=(0.0, 0.0), yaw=c["yaw0"])
            obs = closed_loop.observe(sim)
            if obs.toppled:
                continue
            try:
                plan = planner.plan(obs.cloud, obs.pose, Goal(Pose2D(*c["goal"]), 0.02, math.radians(10.0)),
                                    mass=sim.mass)
            except PlanningError as exc:
                print(f"{shape.name:<26} refused: {exc}")
                continue
            rec = closed_loop.execute(sim, plan)
            real0, real1 = float(rec["ang_vel"][0][2]), float(rec["ang_vel"][1][2])
            model1 = float(plan.trajectory.ang_vels[1][2])
            turn_pred = math.degrees(float(yaw_of(plan.trajectory.orientations[-1])))
            turn_real = math.degrees(float(wrap_angle(closed_loop.observe(sim).pose.yaw - obs.pose.yaw)))
            rows.append((float(plan.ang_vel[2]), real0, model1, real1, turn_pred, turn_real))
            print(f"{shape.name:<26} w_z planned {plan.ang_vel[2]:6.2f} real {real0:6.2f} | after one step model "
                  f"{model1:6.2f} real {real1:6.2f} rad/s | turn predicted {turn_pred:6.1f} real {turn_real:6.1f} deg")
    a = np.array(rows) if rows else np.zeros((0, 6))
    spun = np.abs(a[:, 1]) >= 1.0

    def median_ratio(num: np.ndarray, den: np.ndarray) -> float | None:
        ok = spun & (np.abs(den) > 1e-6)
        return round(float(np.median(num[ok] / den[ok])), 3) if ok.any() else None

    out = {"trials": len(rows), "spun": int(spun.sum()), "model_id": pred.model_id,
           "impulse_spin_ratio_median": median_ratio(a[:, 0], a[:, 1]),
           "step1_spin_ratio_median": median_ratio(a[:, 2], a[:, 3]),
           "turn_ratio_median": median_ratio(a[:, 5], a[:, 4])}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
