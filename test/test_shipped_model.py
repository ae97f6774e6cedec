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
"""Regression guard for the shipped model (physdyn_ros/models/default.pt) on fixed test-split sequences.

test/fixtures/regression_set.npz holds 20 sequences of shapes never trained on (three per category that move
for more than 8 frames without toppling, two that topple; test/fixtures/make_regression_set.py). The bounds sit
about 1.5x above what the shipped model
measures on them (numbers in physdyn_ros/models/MODEL_CARD.md), so a broken export, a changed frame
convention or a worse model fails here.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physdyn_ros import geometry as geo
from physdyn_ros.resources import DEFAULT_MODEL

FIXTURE = Path(__file__).parent / "fixtures" / "regression_set.npz"
#: bounds on the sliding sequences after 4 s (median over sequences), and on the mean per-step error
MAX_FINAL_POS_CM = 4.0
MAX_FINAL_ROT_DEG = 32.0
MAX_STEP_POS_CM = 0.33


@pytest.fixture(scope="module")
def rollouts():
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load()  # the shipped model
    d = dict(np.load(FIXTURE))
    trajs = [pred.rollout(d["cloud"][i], d["lin_vel"][i, 0], d["ang_vel"][i, 0], horizon=60,
                          position=d["pos"][i, 0], orientation=d["quat"][i, 0]) for i in range(len(d["cloud"]))]
    return pred, d, trajs


def test_shipped_model_is_small_and_documented():
    assert DEFAULT_MODEL.is_file() and DEFAULT_MODEL.stat().st_size <= 30 * 2**20
    card = (DEFAULT_MODEL.parent / "MODEL_CARD.md").read_text()
    from physdyn_ros.predictor import Predictor

    assert Predictor.load().model_id in card  # the card describes this very file


def test_shipped_model_errors_on_fixed_test_sequences(rollouts):
    _, d, trajs = rollouts
    slide = np.flatnonzero(~d["toppled"])
    pos = np.array([np.linalg.norm(trajs[i].positions - d["pos"][i], axis=-1) for i in slide]) * 100  # cm
    rot = np.array([np.degrees(geo.quat_angle_between(trajs[i].orientations, d["quat"][i])) for i in slide])
    final_pos, final_rot = float(np.median(pos[:, -1])), float(np.median(rot[:, -1]))
    step = float(np.mean(np.linalg.norm(np.diff(np.array([trajs[i].positions for i in slide]), axis=1)
                                        - np.diff(d["pos"][slide], axis=1), axis=-1))) * 100
    print(f"final position {final_pos:.2f} cm, final rotation {final_rot:.2f} deg, per step {step:.3f} cm")
    assert final_pos < MAX_FINAL_POS_CM and final_rot < MAX_FINAL_ROT_DEG and step < MAX_STEP_POS_CM


def test_shipped_model_flags_toppling(rollouts):
    _, d, trajs = rollouts
    prob = np.array([t.topple_probability for t in trajs])
    assert np.all(prob[d["toppled"]] > 0.5), prob[d["toppled"]]
    assert np.mean(prob[~d["toppled"]] < 0.5) >= 0.7, prob[~d["toppled"]]


def test_shipped_ensemble_members_are_their_own_models_and_as_good():
    """Each shipped member (models/ensemble-*.pt) is a checkpoint of its own (model id, topple head), steps like the
    shipped model, is documented in the model card, and meets the shipped model's bounds on the fixed sequences."""
    from physdyn_ros.predictor import Predictor
    from physdyn_ros.resources import ensemble_models

    lead = Predictor.load()
    card = (DEFAULT_MODEL.parent / "MODEL_CARD.md").read_text()
    paths = ensemble_models()
    assert len(paths) == 4
    total = DEFAULT_MODEL.stat().st_size + sum(p.stat().st_size for p in paths)
    assert total <= 30 * 2**20
    d = dict(np.load(FIXTURE))
    slide = np.flatnonzero(~d["toppled"])
    ids = {lead.model_id}
    for path in paths:
        member = Predictor.load(path)
        assert member.model_id not in ids and member.model_id in card and member.dt == lead.dt
        ids.add(member.model_id)
        trajs = [member.rollout(d["cloud"][i], d["lin_vel"][i, 0], d["ang_vel"][i, 0], horizon=60,
                                position=d["pos"][i, 0], orientation=d["quat"][i, 0]) for i in range(len(d["cloud"]))]
        final = np.array([np.linalg.norm(trajs[i].positions[-1] - d["pos"][i, -1]) for i in slide]) * 100
        assert np.median(final) < MAX_FINAL_POS_CM, (path.name, np.median(final))
        assert all(trajs[i].topple_probability > 0.5 for i in np.flatnonzero(d["toppled"])), path.name
