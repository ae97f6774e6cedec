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
"""The planner's plans stay bit-identical: fixed requests, recorded answers (test/fixtures/plans.json).

Each case plans one push (or expects a refusal) with a fresh planner under a time budget too large to bind, so
the search is a pure function of the request: every float of the plan (impulse, contact point, velocities,
predicted rest pose and errors, topple probabilities, spread), the search's counts, a digest of the predicted
trajectory, and every refusal's message must match the recording exactly. Restructuring code (planning/,
shapes/, the roll-out kernels of learn/) must not move a bit; a change that means to change plans regenerates
the recording on purpose:

    PHYSDYN_REGEN_FIXTURES=1 .venv/bin/python -m pytest -q test/test_plan_identity.py

The recording names the build it was made with (test_rollout_identity.build_env: torch, numpy, CPU capability, model):
float32 BLAS kernels differ between builds and instruction sets, so on another one the plan must still be the
same push (every count, flag and message as recorded) and its floats equal within
float32 rounding (OTHER_BUILD_REL), the trajectory's digest aside. Batch-1 roll-outs run the numpy kernel here
(the C kernel's rounding is bounded by test_native_kernel).

The models: the closed-form sliding model (numpy only) and the shipped learned model (its roll-out kernels on
CPU, torch held to one thread so that the float32 reductions run in one order). The clouds: a box and shapes of
the procedural catalogue (a paper category and new families), so the shapes package is pinned too.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from physdyn_ros.planning import (AnalyticSlidingModel, Goal, PlannerConfig, PlanningError, Pose2D, PushPlan,
                                  PushPlanner, TableBounds)

FIXTURE = Path(__file__).with_name("fixtures") / "plans.json"
BUILD_KEY = "_build"
OTHER_BUILD_REL = 1e-4
REGENERATE = os.environ.get("PHYSDYN_REGEN_FIXTURES") == "1"

#: The search's own limits; the time budget never binds (an hour), so timing cannot change a plan.
BASE = PlannerConfig(time_budget=3600.0, samples=48, max_iterations=3, seed=0)


def box_cloud(center=(0.0, 0.0), half=(0.05, 0.04, 0.03), n: int = 400, seed: int = 0) -> np.ndarray:
    """Points on the faces of an axis-aligned box resting on the table, table frame."""
    rng = np.random.default_rng(seed)
    h = np.asarray(half)
    pts = rng.uniform(-1.0, 1.0, size=(n, 3))
    axis = rng.integers(0, 3, size=n)
    pts[np.arange(n), axis] = np.sign(pts[np.arange(n), axis])
    return pts * h + np.array([center[0], center[1], h[2]])


def shape_cloud(category: str, index: int, xy=(0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """The surface samples of a catalogue shape, resting upright at (xy, yaw), table frame."""
    from physdyn_ros.shapes import make_procedural

    shape = make_procedural(category, index, seed=0)
    c, s = math.cos(yaw), math.sin(yaw)
    pts = np.asarray(shape.points, dtype=np.float64) @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return pts + np.array([xy[0], xy[1], -float(shape.vertices[:, 2].min())])


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()


def _floats(a: Any) -> list[float]:
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


def _record(plan: PushPlan) -> dict[str, Any]:
    """Everything a plan says, exactly (Python floats round-trip through JSON bit for bit); not its wall time."""
    t = plan.trajectory
    return {
        "impulse": _floats(plan.impulse), "contact_point": _floats(plan.contact_point),
        "lin_vel": _floats(plan.lin_vel), "ang_vel": _floats(plan.ang_vel), "mass": float(plan.mass),
        "offset": float(plan.offset), "contact_height": float(plan.contact_height),
        "final_pose": [plan.final_pose.x, plan.final_pose.y, plan.final_pose.yaw],
        "final_position": _floats(plan.final_position), "position_error": float(plan.position_error),
        "yaw_error": float(plan.yaw_error), "topple_probability": float(plan.topple_probability),
        "robust_topple_probability": float(plan.robust_topple_probability), "spread": float(plan.spread),
        "physics_topple_probability": float(plan.physics_topple_probability),
        "within_tolerance": bool(plan.within_tolerance), "iterations": int(plan.iterations),
        "rollouts": int(plan.rollouts), "horizon": int(plan.horizon), "body_source": plan.body_source,
        "trajectory": _digest(t.positions, t.orientations, t.lin_vels, t.ang_vels, t.topple_prob),
        # the message ends with the wall time ("... in 12 ms"): compare what comes before it
        "message": plan.message.rsplit(" roll-outs in ", 1)[0],
    }


# ------------------------------------------------------------------------------------------------- the cases
def _analytic() -> AnalyticSlidingModel:
    return AnalyticSlidingModel(friction=0.5)


def _shipped() -> Any:
    from physdyn_ros.predictor import Predictor

    return Predictor.load()


#: name -> (model factory, request). A request: shape (cloud or "code" for the shape code of the cloud), start,
#: goal, config, mass.
Case = tuple[Callable[[], Any], dict[str, Any]]
CASES: dict[str, Case] = {
    "sliding_box_yaw_goal": (_analytic, dict(cloud=box_cloud(), start=(0.0, 0.0, 0.0),
                                             goal=Goal(Pose2D(0.18, 0.06, 0.5), 0.02, math.radians(10)))),
    "sliding_box_any_yaw_no_robust_check": (_analytic, dict(
        cloud=box_cloud(center=(0.1, -0.05), seed=2), start=(0.1, -0.05, 0.0),
        goal=Goal(Pose2D(-0.05, 0.1, 0.0), 0.02, math.pi), config=replace(BASE, robust_candidates=0, seed=2))),
    "sliding_bottle": (_analytic, dict(cloud=shape_cloud("bottle", 3, (0.05, 0.0), 0.4), start=(0.05, 0.0, 0.4),
                                       goal=Goal(Pose2D(0.2, -0.1, 0.0), 0.02, math.radians(15)), mass=0.4)),
    "sliding_prism_family": (_analytic, dict(cloud=shape_cloud("prism", 2), start=(0.0, 0.0, 0.0),
                                             goal=Goal(Pose2D(0.0, 0.2, -0.8), 0.03, math.radians(20)),
                                             config=replace(BASE, physics_check=False))),
    "sliding_already_there": (_analytic, dict(cloud=box_cloud(center=(0.1, 0.1)), start=(0.1, 0.1, 0.2),
                                              goal=Goal(Pose2D(0.105, 0.1, 0.2)))),
    "refused_unreachable": (_analytic, dict(cloud=box_cloud(), start=(0.0, 0.0, 0.0),
                                            goal=Goal(Pose2D(3.0, 0.0, 0.0)), config=replace(BASE, table=None))),
    "refused_start_off_table": (_analytic, dict(cloud=box_cloud(), start=(0.0, 0.0, 0.0),
                                                goal=Goal(Pose2D(0.2, 0.0, 0.0)),
                                                config=replace(BASE, table=TableBounds(0.1, 1.0, -1.0, 1.0)))),
    "refused_no_contact_height": (_analytic, dict(cloud=box_cloud(), start=(0.0, 0.0, 0.0),
                                                  goal=Goal(Pose2D(0.2, 0.0, 0.0)),
                                                  config=replace(BASE, min_contact_height=0.2,
                                                                 max_contact_height=0.3))),
    "refused_too_fast_spin": (_analytic, dict(cloud=box_cloud(half=(0.03, 0.03, 0.03)), start=(0.0, 0.0, 0.0),
                                              goal=Goal(Pose2D(0.1, 0.05, 2.5), 0.02, math.radians(5)),
                                              config=replace(BASE, max_spin=0.05, robust_candidates=0))),
    "learned_box_yaw_goal": (_shipped, dict(cloud=box_cloud(), start=(0.0, 0.0, 0.0),
                                            goal=Goal(Pose2D(0.15, 0.05, 0.3), 0.02, math.radians(10)))),
    "learned_mug_any_yaw": (_shipped, dict(cloud=shape_cloud("mug", 1, (-0.1, 0.05), 1.0), start=(-0.1, 0.05, 1.0),
                                           goal=Goal(Pose2D(0.1, 0.0, 0.0), 0.03, math.pi),
                                           config=replace(BASE, seed=5))),
    "learned_shape_code_box": (_shipped, dict(cloud=box_cloud(half=(0.04, 0.03, 0.05), seed=3), code=True,
                                              start=(0.0, 0.0, 0.0),
                                              goal=Goal(Pose2D(0.2, -0.05, 0.0), 0.02, math.pi))),
    "learned_refused_topple": (_shipped, dict(cloud=box_cloud(half=(0.02, 0.02, 0.12), seed=4),
                                              start=(0.0, 0.0, 0.0), goal=Goal(Pose2D(0.3, 0.0, 0.0), 0.02, math.pi),
                                              config=replace(BASE, min_contact_height=0.1))),
}


def run_case(model: Any, request: dict[str, Any]) -> dict[str, Any]:
    """The recorded answer to one request: the plan's record, or the refusal's message."""
    planner = PushPlanner(model, request.get("config", BASE))  # fresh: no timing carried over between cases
    cloud = request["cloud"]
    shape = model.encode(cloud) if request.get("code") else cloud
    try:
        plan = planner.plan(shape, request["start"], request["goal"], cloud=None, mass=request.get("mass"))
    except PlanningError as exc:
        return {"refused": str(exc)}
    return {"plan": _record(plan)}


@pytest.fixture(scope="module")
def answers() -> dict[str, dict[str, Any]]:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one reduction order for the float32 roll-outs; restored for the other tests
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PHYSDYN_BATCH1_KERNEL", "numpy")
        try:
            return _answers()
        finally:
            torch.set_num_threads(threads)


def _answers() -> dict[str, dict[str, Any]]:
    """Every case's answer, each model made once."""
    models: dict[Callable[[], Any], Any] = {}
    out = {}
    for name, (factory, request) in CASES.items():
        if factory not in models:
            models[factory] = factory()
        out[name] = run_case(models[factory], request)
    return out


def _masked(text: str) -> str:
    """A message with its numbers masked: their last printed digit may round either way on another build."""
    return re.sub(r"-?\d+(\.\d+)?", "#", text)


def _same_within_rounding(want: Any, got: Any) -> bool:
    """Equal (messages with their numbers masked), floats (and lists of them) within OTHER_BUILD_REL of their
    magnitude (at least 1)."""
    if isinstance(want, str):
        return isinstance(got, str) and _masked(want) == _masked(got)
    if isinstance(want, (bool, int)):
        return want == got
    a, b = np.asarray(want, dtype=np.float64), np.asarray(got, dtype=np.float64)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= OTHER_BUILD_REL * np.maximum(np.abs(a), 1.0)))


def test_plans_are_bit_identical(answers):
    if REGENERATE:
        from test_rollout_identity import build_env

        FIXTURE.write_text(json.dumps({**answers, BUILD_KEY: build_env()}, indent=1, sort_keys=True) + "\n")
        pytest.skip(f"regenerated {FIXTURE.name} ({len(answers)} cases)")
    from test_rollout_identity import build_env

    recorded = json.loads(FIXTURE.read_text())
    written_on = recorded.pop(BUILD_KEY)
    assert sorted(recorded) == sorted(CASES), "the cases and the recording differ: regenerate on purpose"
    exact = written_on == build_env()
    differ = []
    for name, want in recorded.items():
        got = answers[name]
        if "plan" in want and "plan" in got and not exact:
            w, g = want["plan"], got["plan"]
            keys = sorted(k for k in set(w) | set(g) if k != "trajectory"
                          and (k not in w or k not in g or not _same_within_rounding(w[k], g[k])))
            if keys:
                differ.append(f"{name}: {keys}")
        elif "refused" in want and "refused" in got and not exact:
            if _masked(want["refused"]) != _masked(got["refused"]):
                differ.append(f"{name}: {(want, got)}")
        elif got != want:
            keys = sorted(k for k in {**want.get("plan", {}), **got.get("plan", {})}
                          if want.get("plan", {}).get(k) != got.get("plan", {}).get(k))
            differ.append(f"{name}: {keys or (want, got)}")
    how = "bit for bit" if exact else f"within {OTHER_BUILD_REL:g} (recorded on {written_on}; this is {build_env()})"
    assert not differ, f"plans changed ({how}):\n" + "\n".join(differ)


def test_the_cases_cover_plans_and_refusals():
    """The recording holds plans of both models and refusals of several kinds (not only one path)."""
    recorded = json.loads(FIXTURE.read_text())
    assert recorded.pop(BUILD_KEY).startswith("torch ")
    plans = [n for n, a in recorded.items() if "plan" in a]
    refusals = [a["refused"] for a in recorded.values() if "refused" in a]
    assert any(n.startswith("learned") for n in plans) and any(n.startswith("sliding") for n in plans)
    assert len(refusals) >= 4 and len(set(refusals)) == len(refusals)
