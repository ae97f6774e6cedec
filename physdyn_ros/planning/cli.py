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
"""`physdyn plan`: plan a push to a goal pose with the learned model, and optionally execute it in pybullet.

    physdyn plan --category mug --shape-seed 3 --goal 0.2 0.1 45 --execute --max-pushes 3
    physdyn plan --cloud object.ply --start 0.4 0 0 --goal 0.55 0.05 0 --yaw-tolerance 180

With --category / --mesh the object is spawned in the pybullet simulator at the start pose and observed there
(its surface points in the table frame); with --cloud the points come from a file (planning only).
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Any


from .planner import PushPlanner
from .types import Goal, PlannerConfig, PlanningError, Pose2D, PushPlan


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group()
    src.add_argument("--category", default="box", help="procedural category or pybullet_data (default box)")
    src.add_argument("--mesh", default="", help="mesh file (OBJ/STL/PLY, metres, z up) to simulate")
    src.add_argument("--cloud", default="", help="object points in the table frame (.npy/.ply/.xyz): plan only")
    parser.add_argument("--shape-seed", type=int, default=0, help="which shape of the category (default 0)")
    parser.add_argument("--scale", nargs=3, type=float, default=(1.0, 1.0, 1.0), metavar=("SX", "SY", "SZ"))
    parser.add_argument("--start", nargs=3, type=float, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "YAW_DEG"),
                        help="object pose now: m, m, degrees (default 0 0 0)")
    parser.add_argument("--goal", nargs=3, type=float, required=True, metavar=("X", "Y", "YAW_DEG"))
    parser.add_argument("--tolerance", type=float, default=0.02, help="position tolerance, m (default 0.02)")
    parser.add_argument("--yaw-tolerance", type=float, default=10.0, help="degrees; >= 180 ignores yaw (default 10)")
    parser.add_argument("--max-speed", type=float, default=PlannerConfig.max_speed, help="m/s")
    parser.add_argument("--max-topple", type=float, default=PlannerConfig.max_topple_probability,
                        help="reject pushes more likely to topple than this")
    parser.add_argument("--time-budget", type=float, default=PlannerConfig.time_budget, help="s per plan")
    parser.add_argument("--friction", type=float, default=0.5, help="friction of the simulated table (--execute)")
    parser.add_argument("--execute", action="store_true", help="push the object in pybullet and report the outcome")
    parser.add_argument("--max-pushes", type=int, default=1, help="with --execute: re-plan up to this many pushes")
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped model)")
    parser.add_argument("--ensemble", type=int, default=0,
                        help="models in the robustness check: the model and the shipped members (only with the "
                             "shipped model); 1: the model alone; 0 (default): every shipped member, none with --model")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def plan_dict(plan: PushPlan) -> dict[str, Any]:
    return {"lin_vel": plan.lin_vel.tolist(), "ang_vel": plan.ang_vel.tolist(), "impulse": plan.impulse.tolist(),
            "contact_point": plan.contact_point.tolist(), "mass": plan.mass,
            "predicted_final_pose": [plan.final_pose.x, plan.final_pose.y, math.degrees(plan.final_pose.yaw)],
            "predicted_position_error_m": plan.position_error,
            "predicted_yaw_error_deg": math.degrees(plan.yaw_error), "topple_probability": plan.topple_probability,
            "within_tolerance": plan.within_tolerance, "planning_time_s": plan.planning_time,
            "rollouts": plan.rollouts, "model_id": plan.model_id, "message": plan.message}


def _print_plan(plan: PushPlan, prefix: str = "") -> None:
    v, w, j, c = plan.lin_vel, plan.ang_vel, plan.impulse, plan.contact_point
    print(f"{prefix}push: v = [{v[0]:.3f}, {v[1]:.3f}] m/s, w_z = {w[2]:.2f} rad/s; impulse [{j[0]:.4f}, "
          f"{j[1]:.4f}] N s at [{c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}] m (mass {plan.mass:.3f} kg)")
    print(f"{prefix}predicted rest: ({plan.final_pose.x:.3f}, {plan.final_pose.y:.3f}) m, yaw "
          f"{math.degrees(plan.final_pose.yaw):.1f} deg; {plan.message}")


def run(args: argparse.Namespace) -> int:
    from ..predictor import Predictor, load_cloud
    from ..resources import ensemble_paths

    start = Pose2D(args.start[0], args.start[1], math.radians(args.start[2]))
    yaw_tol = math.pi if args.yaw_tolerance >= 180 else math.radians(args.yaw_tolerance)
    goal = Goal(Pose2D(args.goal[0], args.goal[1], math.radians(args.goal[2])), args.tolerance, yaw_tol)
    config = PlannerConfig(max_speed=args.max_speed, max_topple_probability=args.max_topple,
                           time_budget=args.time_budget)
    if args.execute and args.cloud:
        raise PlanningError("--execute needs an object to simulate (--category or --mesh), not --cloud")
    if args.max_pushes < 1:
        raise PlanningError(f"--max-pushes must be >= 1, got {args.max_pushes}")
    try:
        paths = ensemble_paths(args.ensemble, args.model or "")
    except ValueError as exc:
        raise PlanningError(f"--ensemble: {exc}") from None
    members = [Predictor.load(m, threads=1) for m in paths]
    planner = PushPlanner(Predictor.load(args.model, threads=1), config, ensemble=members)
    planner.warm_up()
    if args.cloud:
        plan = planner.plan(load_cloud(args.cloud), start, goal)
        print(json.dumps(plan_dict(plan), indent=1)) if args.json else _print_plan(plan)
        return 0

    from ..shapes import resolve_shape
    from ..sim.simulator import SimConfig, Simulator
    from .closed_loop import observe, push_to_goal

    shape = resolve_shape(args.category, args.shape_seed, args.mesh)
    with Simulator(SimConfig(friction=args.friction)) as sim:
        sim.spawn(shape, args.scale, xy=(start.x, start.y), yaw=start.yaw)
        obs = observe(sim)
        start = obs.pose  # the settled pose
        if not args.execute:
            plan = planner.plan(obs.cloud, start, goal, mass=sim.mass)
            print(json.dumps(plan_dict(plan), indent=1)) if args.json else _print_plan(plan)
            return 0
        result = push_to_goal(sim, planner, goal, max_pushes=args.max_pushes, mass=sim.mass)
    assert result.final_pose is not None  # push_to_goal always ends with the observed pose
    if args.json:
        print(json.dumps({"success": result.success, "message": result.message,
                          "final_pose": [result.final_pose.x, result.final_pose.y,
                                         math.degrees(result.final_pose.yaw)],
                          "position_error_m": result.position_error,
                          "yaw_error_deg": math.degrees(result.yaw_error),
                          "pushes": [dict(plan_dict(p.plan), real_final_pose=[p.final_pose.x, p.final_pose.y,
                                                                              math.degrees(p.final_pose.yaw)],
                                          real_position_error_m=p.position_error, toppled=p.toppled)
                                     for p in result.pushes]}, indent=1))
    else:
        print(f"object {shape.name}: start ({start.x:.3f}, {start.y:.3f}) m, yaw {math.degrees(start.yaw):.1f} deg")
        for k, p in enumerate(result.pushes, 1):
            _print_plan(p.plan, f"[{k}] ")
            print(f"[{k}] real rest: ({p.final_pose.x:.3f}, {p.final_pose.y:.3f}) m, yaw "
                  f"{math.degrees(p.final_pose.yaw):.1f} deg: {100 * p.position_error:.1f} cm, "
                  f"{math.degrees(p.yaw_error):.1f} deg from the goal" + (" (toppled)" if p.toppled else ""))
        print(("SUCCESS: " if result.success else "FAILED: ") + result.message)
    return 0 if result.success else 1
