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
"""The prediction's spread (physdyn_ros.spread): perturbations, the conformal fit, the calibration file and the
Predictor's radii."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from physdyn_ros import spread as S
from physdyn_ros.predictor import Predictor
from physdyn_ros.resources import DEFAULT_MODEL

RNG = np.random.default_rng(11)
BOX = RNG.uniform(-1, 1, (1200, 3)) * (0.05, 0.03, 0.04) + (0.2, 0.1, 0.04)


@pytest.fixture(scope="module")
def shipped() -> Predictor:
    return Predictor.load(DEFAULT_MODEL, threads=1)


def test_perturbed_twists_scale_the_impulse():
    lin, ang = S.perturbed_twists(np.array([0.4, 0.1, 0.0]), np.array([0.0, 0.0, 2.0]))
    assert lin.shape == ang.shape == (len(S.SPEEDS), 3)
    np.testing.assert_allclose(lin, [[0.36, 0.09, 0.0], [0.44, 0.11, 0.0]])
    assert ang[:, 2] == pytest.approx([1.8, 2.2])  # the same contact: the spin scales with the speed


def test_observed_states_keep_the_spread(shipped):
    """A refinement (observed states after the push) perturbs the observed velocities too: otherwise the
    observation washes the perturbation out and the radius shrinks to its floor while the error does not."""
    code = shipped.encode(BOX)
    v, w = np.array([2.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])  # slides for about 6 frames
    free = shipped.rollout(code, v, w, 60)
    obs = {"positions": free.positions[1:3], "orientations": free.orientations[1:3], "lin_vels": free.lin_vels[1:3],
           "ang_vels": free.ang_vels[1:3]}
    assert np.linalg.norm(free.lin_vels[2]) > 0.5  # still sliding when the model takes over
    before = shipped.rollout(code, v, w, 60, spread=True).spread
    after = shipped.rollout(code, v, w, 60, observed=obs, spread=True).spread
    assert after.sensitivity[0] > 0.2 * before.sensitivity[0] > 0.002


def test_the_conformal_factors_cover_fresh_pushes_at_their_level():
    """Errors proportional to the sensitivity with a heavy-tailed factor: the fitted radii hold the stated share of
    pushes drawn afresh (a factor off by 20 % misses the 0.9 level by far more than the tolerance)."""
    rng = np.random.default_rng(2)

    def draw(n):
        sens = np.column_stack([rng.uniform(0.001, 0.05, n), rng.uniform(0.01, 0.3, n)])
        return sens, sens * np.abs(rng.standard_t(3, (n, 2)))

    sens, err = draw(8000)
    pos, yaw = S.fit_calibration(sens, err)
    cal = S.SpreadCalibration("m", S.LEVELS, pos, yaw)
    sens2, err2 = draw(20000)
    for level in S.LEVELS:
        radii = np.array([cal.radii(tuple(s), level) for s in sens2])
        assert np.mean(err2 <= radii, axis=0) == pytest.approx([level, level], abs=0.02)
    assert list(pos) == sorted(pos)  # wider radii for higher levels
    with pytest.raises(ValueError, match="level 0.75 not calibrated"):
        cal.radii((0.01, 0.1), 0.75)
    with pytest.raises(ValueError, match="at least 20 pushes"):
        S.fit_calibration(sens[:5], err[:5])
    with pytest.raises(ValueError, match=r"both be \(n, 2\)"):
        S.fit_calibration(sens[:, 0], err[:, 0])


def test_a_push_that_barely_moves_keeps_the_floor():
    cal = S.SpreadCalibration("m", (0.9,), (2.0,), (3.0,))
    assert cal.radii((0.0, 0.0)) == pytest.approx((2.0 * S.FLOORS[0], 3.0 * S.FLOORS[1]))


def test_the_calibration_file_round_trips_and_bad_files_are_named(tmp_path):
    cal = S.SpreadCalibration("abc", (0.5, 0.8, 0.9, 0.95), (0.4, 1.0, 1.7, 2.9), (0.9, 2.9, 4.8, 11.0), fitted_on="x",
                              pushes=9)
    path = tmp_path / "m.spread.json"
    cal.save(path)
    assert S.SpreadCalibration.load(path) == cal
    assert [p.name for p in tmp_path.iterdir()] == ["m.spread.json"]  # no temporary file left behind
    raw = json.loads(path.read_text())
    for key, value, match in (("position_factors", [1.0, -2.0, 3.0, 4.0], "positive finite factor"),
                              ("levels", [0.5, 0.8], "one positive finite factor per level"),
                              ("model_id", 3, "model_id must be a string")):
        path.write_text(json.dumps({**raw, key: value}))
        with pytest.raises(ValueError, match=match):
            S.SpreadCalibration.load(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="not a spread calibration"):
        S.SpreadCalibration.load(path)
    with pytest.raises(FileNotFoundError):
        S.SpreadCalibration.load(tmp_path / "none.json")


def test_the_shipped_model_has_its_calibration(shipped):
    cal = shipped.spread_calibration
    assert cal is not None, shipped.spread_problem
    assert cal.model_id == shipped.model_id and cal.pushes >= 500


def test_the_spread_leaves_the_prediction_alone_and_grows_with_the_push(shipped):
    """The same trajectory with and without the spread; a fast push's rest pose is less certain than a slow
    one's; the radii are the calibration's factor times the floored sensitivity."""
    code = shipped.encode(BOX)
    plain = shipped.rollout(code, (0.3, 0.0, 0.0), (0.0, 0.0, 0.5), 60)
    with_spread = shipped.rollout(code, (0.3, 0.0, 0.0), (0.0, 0.0, 0.5), 60, spread=True)
    assert plain.spread is None
    np.testing.assert_array_equal(plain.positions, with_spread.positions)
    np.testing.assert_array_equal(plain.topple_prob, with_spread.topple_prob)
    s = with_spread.spread
    assert s.level == S.DEFAULT_LEVEL and 0 <= s.topple <= 0.5
    assert (s.position, s.yaw) == pytest.approx(shipped.spread_calibration.radii(s.sensitivity))
    fast = shipped.rollout(code, (1.0, 0.0, 0.0), (0.0, 0.0, 0.5), 60, spread=True).spread
    assert fast.position > 2 * s.position


def test_a_calibration_of_another_model_is_not_used(shipped, tmp_path):
    """The radii of a checkpoint whose calibration names another model are NaN, and spread_problem says why."""
    import shutil

    ckpt = tmp_path / "copy.pt"
    shutil.copy(DEFAULT_MODEL, ckpt)
    replace(shipped.spread_calibration, model_id="other").save(S.spread_path(ckpt))
    pred = Predictor.load(ckpt, threads=1)
    assert pred.spread_calibration is None and "fitted for model other" in pred.spread_problem
    s = pred.rollout(pred.encode(BOX), (0.3, 0.0, 0.0), (0.0, 0.0, 0.0), 30, spread=True).spread
    assert math.isnan(s.position) and math.isnan(s.yaw) and math.isfinite(s.topple)


def test_within_level_bounds_the_chance_of_ending_within():
    cal = S.SpreadCalibration("m", (0.5, 0.8, 0.9, 0.95), (1.0, 2.0, 3.0, 4.0), (1.0, 2.0, 3.0, 4.0))
    sens = (0.01, 0.1)  # radii 1-4 cm and 0.1-0.4 rad at the four levels
    assert cal.within_level(sens, 0.035) == 0.9  # the yaw ignored
    assert cal.within_level(sens, 0.035, 0.5) == pytest.approx(0.85)  # both: the union bound 0.9 + 0.95 - 1
    assert cal.within_level(sens, 0.035, 0.15) == pytest.approx(0.4)
    assert cal.within_level(sens, 0.035, 0.05) == 0.0  # no yaw level fits
    assert cal.within_level(sens, 0.005) == 0.0 and cal.within_level(sens, -0.01) == 0.0


def test_the_plans_success_estimate_follows_the_tolerance(shipped):
    """A plan's success_probability: near the top level for a wide tolerance, 0 for one tighter than any radius."""
    from physdyn_ros.planning import Goal, PlannerConfig, Pose2D, PushPlanner

    cfg = PlannerConfig(time_budget=5.0, samples=32, max_iterations=2, seed=0, physics_check=False)
    planner = PushPlanner(shipped, cfg)
    start = Pose2D(0.2, 0.1, 0.0)
    wide = planner.plan(BOX, start, Goal(Pose2D(0.45, 0.1, 0.0), position_tolerance=0.1, yaw_tolerance=math.pi))
    assert 0.5 < wide.success_probability <= 0.95 * (1 - wide.topple_probability) + 1e-9, wide.message
    tight = planner.plan(BOX, start, Goal(Pose2D(0.45, 0.1, 0.0), position_tolerance=0.001, yaw_tolerance=math.pi))
    assert tight.success_probability == 0.0
    already = planner.plan(BOX, start, Goal(Pose2D(0.21, 0.1, 0.0), position_tolerance=0.02, yaw_tolerance=math.pi))
    assert already.success_probability == 1.0 and already.speed == 0.0  # no push needed


def test_the_topple_spread_is_the_models_own_with_the_fusion_on(shipped):
    """With topple_fusion the trajectory's probability is the fused one, but the topple spread stays the standard
    deviation of the model's own probabilities over the three pushes (a fused one beside two unfused ones would
    measure the fusion's correction, not the push's sensitivity)."""
    fused = Predictor.load(DEFAULT_MODEL, threads=1, topple_fusion=True)
    try:
        tall = np.random.default_rng(5).uniform(-1, 1, (1500, 3)) * (0.02, 0.02, 0.12) + (0.2, 0.1, 0.12)
        args = (tall, (0.3, 0.0, 0.0), (0.0, 0.0, 0.0), 60, (0.2, 0.1, 0.12))
        a, b = fused.rollout(*args, spread=True), shipped.rollout(*args, spread=True)
        assert abs(a.topple_probability - b.topple_probability) > 0.05  # the fusion moved the probability
        assert a.spread.topple == pytest.approx(b.spread.topple, abs=1e-12)
    finally:
        fused.close()


def test_a_calibration_without_the_messages_level_is_not_used(shipped, tmp_path):
    import shutil

    ckpt = tmp_path / "copy.pt"
    shutil.copy(DEFAULT_MODEL, ckpt)
    S.SpreadCalibration(shipped.model_id, (0.5, 0.8), (0.4, 1.0), (0.9, 2.9)).save(S.spread_path(ckpt))
    pred = Predictor.load(ckpt, threads=1)
    assert pred.spread_calibration is None and "no level 0.9" in pred.spread_problem
    assert math.isnan(pred.rollout(pred.encode(BOX), (0.3, 0.0, 0.0), (0.0, 0.0, 0.0), 30, spread=True).spread.position)


def test_fit_command_writes_a_calibration_the_predictor_loads(shipped, tmp_path, capsys):
    """`physdyn fit-spread` on a small real dataset: a calibration beside the checkpoint, for its model, which the
    Predictor then uses; too few pushes are refused with one line."""
    from learn_support import tiny_dataset

    from physdyn_ros.cli import main

    data = tiny_dataset()
    ckpt = tmp_path / "default.pt"
    ckpt.symlink_to(DEFAULT_MODEL)
    assert main(["fit-spread", "--data", str(data), "--checkpoint", str(ckpt), "--splits", "train", "val", "test",
                 "--max-sequences", "120"]) == 0
    cal = S.SpreadCalibration.load(S.spread_path(ckpt))
    assert cal.model_id == shipped.model_id and cal.levels == S.LEVELS and 20 <= cal.pushes <= 120
    assert list(cal.position_factors) == sorted(cal.position_factors) and cal.fitted_on == "data (train, val, test)"
    assert Predictor.load(ckpt, threads=1).spread_calibration == cal
    assert main(["fit-spread", "--data", str(data), "--checkpoint", str(ckpt), "--max-sequences", "5"]) == 2
    assert "--max-sequences must be at least 20" in capsys.readouterr().err
