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
"""The topple fusion: its weights file, its fit, its physics runs, and the Predictor fusing with them."""
from __future__ import annotations

import json
import os
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from physdyn_ros.learn import rules
from physdyn_ros.predictor import Predictor
from physdyn_ros.resources import DEFAULT_MODEL
from physdyn_ros.topple_fusion import RUNS, FusionWeights, SolidPhysics, fit_weights, fusion_path, logit

WEIGHTS = FusionWeights(model_id="m", model=0.7, physics=(1.4, 1.6, 0.6, 0.3, 0.5), bias=-2.8, fitted_on="x",
                        pushes=10)
TIP = ((0.3, 0.0, 0.0), (0.0, 6.0, 0.0))  # a tall box's push about its lower edge: it tips whatever the run


def box_cloud(extents, n=2000) -> np.ndarray:
    """A box's surface resting on the table plane z = 0, centred at x = y = 0."""
    pts = np.asarray(trimesh.sample.sample_surface(trimesh.creation.box(extents=extents), n, seed=0)[0])
    return pts - [0.0, 0.0, pts[:, 2].min()]


def test_weights_round_trip_and_fuse(tmp_path):
    path = tmp_path / "w.json"
    WEIGHTS.save(path)
    assert FusionWeights.load(path) == WEIGHTS
    assert not list(tmp_path.glob("*.tmp"))  # the temporary file was renamed
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # as any file the user writes, not mkstemp's 0600
    p = WEIGHTS.fuse(np.array([0.5, 0.5, 0.9]), np.array([[0, 0, 0, 0, 0], [1, 1, 1, 1, 1], [0, 1, 0, 0, 1]]))
    z = np.array([-2.8, -2.8 + 4.4, 0.7 * np.log(9.0) + 1.6 + 0.5 - 2.8])
    np.testing.assert_allclose(p, 1.0 / (1.0 + np.exp(-z)))
    assert fusion_path("/a/b/default.pt").as_posix() == "/a/b/default.topple_fusion.json"


def _edited(**changes) -> str:
    raw = json.loads(json.dumps(WEIGHTS.__dict__))
    raw.update(changes)
    return json.dumps(raw)


@pytest.mark.parametrize("content, match", [("{not json", "not topple fusion weights"),
                                            ('{"model_id": "m"}', "not topple fusion weights"),
                                            (_edited(bias=float("nan")), "must be finite"),
                                            (_edited(physics=[1.0, 2.0]), "one weight per run"),
                                            (_edited(runs=[[1.0, 1.0], [0.8, 1.0], [1.2], [1, 1], [1, 1]]),
                                             "one weight per run"),
                                            (_edited(runs=[[1.0, -1.0]] * 5), "one weight per run"),
                                            (_edited(runs=[], physics=[]), "one weight per run"),
                                            (_edited(model=True), "must be finite numbers"),
                                            (_edited(model_id=3), "model_id must be a string")])
def test_bad_weight_files_are_refused(tmp_path, content, match):
    path = tmp_path / "w.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=match):
        FusionWeights.load(path)


def test_fit_recovers_the_weights_that_made_the_data():
    rng = np.random.default_rng(0)
    n = 20000
    p_model = 1.0 / (1.0 + np.exp(-rng.normal(-1.5, 2.0, n)))
    toppled = (rng.random((n, 5)) < 0.3).astype(float)
    truth = rng.random(n) < WEIGHTS.fuse(p_model, toppled)
    coef, bias = fit_weights(p_model, toppled, truth, l2=0.0)
    np.testing.assert_allclose(coef, [0.7, 1.4, 1.6, 0.6, 0.3, 0.5], atol=0.12)
    assert bias == pytest.approx(-2.8, abs=0.12)
    with pytest.raises(ValueError, match="topple and pushes that do not"):
        fit_weights(p_model, toppled, np.zeros(n))


def test_fused_per_step_probabilities_keep_the_timing():
    step = np.array([[0.0, 0.1, 0.2, 0.4], [0.0, 0.3, 0.3, 0.3]])
    per_step, whole = rules.whole_push_topple(step, np.array([0.2, 0.6]), np.zeros(step.shape, bool),
                                              fuse=lambda w: 1.0 - w)
    np.testing.assert_allclose(whole, [0.8, 0.4])
    np.testing.assert_allclose(per_step[0], [0.0, 0.2, 0.4, 0.8])
    np.testing.assert_allclose(per_step[1], [0.0, 0.4, 0.4, 0.4])


def test_solid_physics_tips_a_tall_box_and_slides_a_flat_one():
    all_runs, no_run = [1.0] * len(RUNS), [0.0] * len(RUNS)
    with SolidPhysics(0.5) as physics:
        tall = box_cloud((0.04, 0.04, 0.24))
        ref = np.array([0.0, 0.0, 0.12])
        assert physics.toppled(tall, ref, *TIP).tolist() == all_runs
        assert physics.toppled(tall, ref, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)).tolist() == no_run
        flat = box_cloud((0.2, 0.15, 0.03))
        assert physics.toppled(flat, (0.0, 0.0, 0.015), (0.8, 0.0, 0.0), (0.0, 0.0, 2.0)).tolist() == no_run
        # a spin in place described about a point 0.5 m away, where the body moves at w x r = 2 m/s: taken as the
        # centre of mass's velocity, that slide would tip the box
        spin, far = np.array([0.0, 0.0, 4.0]), ref + [0.5, 0.0, 0.0]
        assert physics.toppled(tall, ref, np.cross(spin, far - ref), spin).tolist() == all_runs
        assert physics.toppled(tall, far, np.cross(spin, far - ref), spin).tolist() == no_run
    # the runs' factors act: a push at the edge of tipping tips only the faster run
    with SolidPhysics(0.5, runs=((1.0, 1.0), (1.0, 1.6))) as physics:
        edge = [physics.toppled(tall, ref, (0.0, 0.0, 0.0), (0.0, s, 0.0)).tolist() for s in np.linspace(1, 5, 9)]
        assert [0.0, 1.0] in edge and [0.0, 0.0] in edge and [1.0, 1.0] in edge and [1.0, 0.0] not in edge
    with pytest.raises(RuntimeError, match="closed"):
        physics.toppled(tall, ref, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="friction"):
        SolidPhysics(-0.5)


@pytest.fixture(scope="module")
def fused(tmp_path_factory):
    """The shipped model beside weights that ignore it (model 0) and follow the nominal physics run."""
    folder = tmp_path_factory.mktemp("fusion")
    ckpt = folder / "default.pt"
    ckpt.symlink_to(DEFAULT_MODEL)
    plain = Predictor.load(ckpt)
    # weights that ignore the model (0) and contradict the first physics run: 0.018 where it tips, 0.982 where not
    replace(WEIGHTS, model_id=plain.model_id, model=0.0, physics=(-8.0, 0.0, 0.0, 0.0, 0.0),
            bias=4.0).save(fusion_path(ckpt))
    return plain, Predictor.load(ckpt, topple_fusion=True)


def test_predictor_fuses_rollouts_of_clouds(fused):
    plain, pred = fused
    tall = box_cloud((0.04, 0.04, 0.24)) + [0.3, 0.1, 0.0]
    code = pred.encode(tall)
    tip, rest = TIP, ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    low, high = 1.0 / (1.0 + np.exp(4.0)), 1.0 / (1.0 + np.exp(-4.0))
    assert plain.rollout(code, *tip).topple_probability > 0.9 and plain.rollout(code, *rest).topple_probability < 0.01
    tipped = pred.rollout(code, *tip)
    assert tipped.topple_probability == pytest.approx(low)
    assert np.all(tipped.orientations[:, :2] == 0.0)  # a "no" at or under 0.5 keeps the roll-out flat
    assert pred.rollout(tall, *rest).topple_probability == pytest.approx(high)
    # a code without points (a shape feature message's) is not fused, nor are batched roll-outs; the positions of
    # a push the fusion does not flip are the model's
    still = pred.rollout(code, *rest), plain.rollout(code, *rest)
    np.testing.assert_array_equal(still[0].positions, still[1].positions)
    bare = replace(code, points=None)
    assert pred.rollout(bare, *tip).topple_probability == plain.rollout(bare, *tip).topple_probability
    np.testing.assert_array_equal(pred.rollout_batch(code, *tip).topple_prob,
                                  plain.rollout_batch(code, *tip).topple_prob)


def test_predictor_simulates_the_cloud_where_it_is(fused):
    """The cloud is the object at the start of the push; position and orientation name that pose and do not move
    it again. A slab 4 cm thick along x tips when pushed along x, not along y: given with an orientation of 90 deg
    yaw, it must still tip along x (turning the cloud by the orientation would have the push along its long side)."""
    _, pred = fused
    slab = box_cloud((0.04, 0.16, 0.2)) + [0.2, -0.1, 0.0]
    yaw90 = (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))
    centre = slab.mean(axis=0)
    with SolidPhysics(0.5) as physics:
        assert physics.toppled(slab, centre, (0.5, 0.0, 0.0), (0.0, 0.0, 0.0)).tolist() == [1.0] * len(RUNS)
        assert physics.toppled(slab, centre, (0.0, 0.5, 0.0), (0.0, 0.0, 0.0)).tolist() == [0.0] * len(RUNS)
    low = 1.0 / (1.0 + np.exp(4.0))  # the fixture's weights: the first run tipped
    assert pred.rollout(slab, (0.5, 0.0, 0.0), (0.0, 0.0, 0.0), position=centre,
                        orientation=yaw90).topple_probability == pytest.approx(low)


def test_small_or_flat_clouds_keep_the_models_probability(fused):
    plain, pred = fused
    few = box_cloud((0.04, 0.04, 0.24), n=12)
    flat = box_cloud((0.1, 0.1, 0.02))
    flat[:, 2] = 0.0
    for cloud in (few, flat):
        assert pred.rollout(cloud, *TIP).topple_probability == plain.rollout(cloud, *TIP).topple_probability


def test_predictor_refuses_missing_or_foreign_weights(tmp_path):
    ckpt = tmp_path / "default.pt"
    ckpt.symlink_to(DEFAULT_MODEL)
    with pytest.raises(FileNotFoundError, match="fit-topple-fusion"):
        Predictor.load(ckpt, topple_fusion=True)
    WEIGHTS.save(fusion_path(ckpt))
    with pytest.raises(ValueError, match="fitted for model m"):
        Predictor.load(ckpt, topple_fusion=True)


def test_logit_is_finite_at_the_ends():
    assert np.all(np.isfinite(logit(np.array([0.0, 1.0]))))


def test_fit_command_writes_weights_the_predictor_loads(tmp_path, capsys):
    """`physdyn fit-topple-fusion` on a small real dataset: weights beside a checkpoint, which then loads fused;
    a checkpoint without a topple head is refused with one line."""
    from learn_support import random_checkpoint, tiny_dataset

    from physdyn_ros.cli import main

    data = tiny_dataset()
    ckpt = tmp_path / "default.pt"
    ckpt.symlink_to(DEFAULT_MODEL)
    assert main(["fit-topple-fusion", "--data", str(data), "--checkpoint", str(ckpt), "--splits", "train", "val",
                 "test", "--max-sequences", "120"]) == 0
    weights = FusionWeights.load(fusion_path(ckpt))
    assert weights.pushes == 120 and weights.fitted_on == "data (train, val, test)"
    assert Predictor.load(ckpt, topple_fusion=True).topple_fusion.weights == weights
    tiny = random_checkpoint(tmp_path / "tiny.pt")
    assert main(["fit-topple-fusion", "--data", str(data), "--checkpoint", str(tiny)]) == 2
    assert "no whole-push topple head" in capsys.readouterr().err
