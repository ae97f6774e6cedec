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
"""The Predictor API: input checking, checkpoint errors, batch = single, steps in, and `physdyn predict`."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from learn_support import random_checkpoint
from physdyn_ros import geometry as geo
from physdyn_ros.learn.checkpoint import CheckpointError
from physdyn_ros.predictor import Observed, Predictor, ShapeCode, Trajectory, load_cloud


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    return random_checkpoint(tmp_path_factory.mktemp("pred") / "tiny.pt")


@pytest.fixture(scope="module")
def pred(model_path):
    return Predictor.load(model_path)


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(0)
    return rng.normal(size=(300, 3)) * [0.08, 0.04, 0.06] + [0.5, -0.2, 0.06]


def test_attributes_and_trajectory_fields(pred, cloud):
    assert pred.model_id.startswith("tiny-") and pred.num_points == 64 and pred.feature_dim == 8
    assert pred.max_horizon == 80 and pred.dt == pytest.approx(1 / 15)
    code = pred.encode(cloud)
    assert isinstance(code, ShapeCode) and code.feature.shape == (8,) and code.num_points == 300
    assert np.allclose(code.centroid, cloud.mean(0)) and np.all(code.half_extents > 0)
    traj = pred.rollout(code, [0.5, 0.1, 0.0], [0.0, 0.0, 2.0], horizon=30)
    assert isinstance(traj, Trajectory) and traj.horizon == 30
    assert traj.positions.shape == (31, 3) and traj.orientations.shape == (31, 4)
    assert traj.lin_vels.shape == traj.ang_vels.shape == (31, 3) and traj.topple_prob.shape == (31,)
    assert np.allclose(traj.positions[0], code.centroid) and np.allclose(traj.orientations[0], [0, 0, 0, 1])
    assert np.allclose(traj.lin_vels[0], [0.5, 0.1, 0.0]) and traj.topple_prob[0] == 0.0
    assert np.allclose(np.linalg.norm(traj.orientations, axis=1), 1)
    assert traj.topple_probability == pytest.approx(traj.topple_prob.max()) and 0 <= traj.topple_probability <= 1
    assert np.allclose(traj.times[-1], 2.0)
    # a raw cloud is encoded on the fly, with the same result
    same = pred.rollout(cloud, [0.5, 0.1, 0.0], [0.0, 0.0, 2.0], horizon=30)
    assert np.allclose(same.positions, traj.positions)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((0, 3)), "empty"),
    (np.zeros((10, 2)), "shape"),
    (np.zeros(5), "shape"),
    (np.array([[0.0, 0.0, np.nan], [1.0, 1.0, 1.0]]), "NaN or inf"),
    (np.array([[0.0, 0.0, np.inf]]), "NaN or inf"),
    ("not a cloud", "cloud"),
])
def test_bad_clouds_raise_value_error(pred, bad, match):
    with pytest.raises(ValueError, match=match):
        pred.encode(bad)
    with pytest.raises(ValueError, match=match):
        pred.rollout(bad, [0.1, 0, 0], [0, 0, 0])


@pytest.mark.parametrize("kwargs, match", [
    ({"lin_vel": [np.nan, 0, 0]}, "lin_vel contains NaN"),
    ({"ang_vel": [0, np.inf, 0]}, "ang_vel contains NaN"),
    ({"lin_vel": [0.1, 0.0]}, r"lin_vel must have shape \(3,\)"),
    ({"horizon": 0}, "horizon must be in 1..80"),
    ({"horizon": 81}, "horizon must be in 1..80"),
    ({"horizon": 2.5}, "integer"),
    ({"horizon": True}, "integer"),
    ({"position": [0, 0]}, "position"),
    ({"orientation": [0, 0, 0, 0]}, "non-zero"),
    ({"orientation": [0, 0, np.nan, 1]}, "NaN"),
])
def test_bad_arguments_raise_value_error(pred, cloud, kwargs, match):
    args = {"lin_vel": [0.3, 0, 0], "ang_vel": [0, 0, 1], "horizon": 20}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        pred.rollout(cloud, **args)


def test_shape_codes_are_checked(pred, cloud):
    code = pred.encode(cloud)
    other = ShapeCode(code.feature, code.heading, code.centroid, code.half_extents, 300, model_id="paper-123")
    with pytest.raises(ValueError, match="encoded by model paper-123"):
        pred.rollout(other, [0.1, 0, 0], [0, 0, 0])
    short = ShapeCode(code.feature[:4], code.heading, code.centroid, code.half_extents, 300)
    with pytest.raises(ValueError, match="8 finite numbers"):
        pred.rollout(short, [0.1, 0, 0], [0, 0, 0])


def test_checkpoint_errors_at_load(tmp_path, model_path, monkeypatch):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        Predictor.load(tmp_path / "missing.pt")
    (tmp_path / "garbage.pt").write_bytes(b"\x00not a torch file" * 10)
    with pytest.raises(CheckpointError, match="corrupt"):
        Predictor.load(tmp_path / "garbage.pt")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(model_path.read_bytes()[:2000])
    with pytest.raises(CheckpointError):
        Predictor.load(truncated)
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a physdyn checkpoint"):
        Predictor.load(tmp_path / "foreign.pt")
    ckpt = torch.load(model_path, weights_only=True)
    torch.save(dict(ckpt, version=99), tmp_path / "future.pt")
    with pytest.raises(CheckpointError, match="version 99"):
        Predictor.load(tmp_path / "future.pt")
    ckpt["config"]["model"]["hidden_size"] = 48
    torch.save(ckpt, tmp_path / "mismatch.pt")
    with pytest.raises(CheckpointError, match="do not fit"):
        Predictor.load(tmp_path / "mismatch.pt")
    import physdyn_ros.resources as res

    monkeypatch.setattr(res, "DEFAULT_MODEL", tmp_path / "models" / "default.pt")
    with pytest.raises(FileNotFoundError, match="no shipped model"):
        Predictor.load()


def test_batch_equals_single(pred, cloud):
    rng = np.random.default_rng(3)
    code = pred.encode(cloud)
    v, w = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    batch = pred.rollout_batch(code, v, w, horizon=25)
    assert len(batch) == 5 and batch.positions.shape == (5, 26, 3) and batch.topple_probability.shape == (5,)
    for i in range(5):
        one = pred.rollout(code, v[i], w[i], horizon=25)
        for name in ("positions", "lin_vels", "ang_vels", "topple_prob"):
            assert np.allclose(getattr(batch[i], name), getattr(one, name), atol=1e-5), name
        assert geo.quat_angle_between(batch[i].orientations, one.orientations).max() < 1e-5
    # many shapes, positions and orientations
    clouds = [cloud, cloud[::2] * 1.3, geo.rotate_yaw(cloud, 1.0)]
    pos, quat = rng.normal(size=(3, 3)), geo.quat_normalize(rng.normal(size=(3, 4)))
    many = pred.rollout_batch(clouds, v[:3], w[:3], 15, positions=pos, orientations=quat)
    for i in range(3):
        one = pred.rollout(clouds[i], v[i], w[i], 15, position=pos[i], orientation=quat[i])
        assert np.allclose(many[i].positions, one.positions, atol=1e-5)
        assert geo.quat_angle_between(many[i].orientations, one.orientations).max() < 1e-5
    with pytest.raises(ValueError, match="batch sizes disagree"):
        pred.rollout_batch(clouds, v, w, 15)


def test_observed_steps_are_kept_and_fed(pred, cloud):
    rng = np.random.default_rng(4)
    k = 3
    obs = Observed(positions=cloud.mean(0) + np.cumsum(rng.normal(size=(k, 3)) * 0.01, 0),
                   orientations=geo.quat_normalize(np.array([[0, 0, 0.05 * i, 1.0] for i in range(1, k + 1)])),
                   lin_vels=rng.normal(size=(k, 3)), ang_vels=rng.normal(size=(k, 3)))
    traj = pred.rollout(cloud, [0.3, 0, 0], [0, 0, 1], horizon=20, observed=obs)
    assert np.allclose(traj.positions[1:k + 1], obs.positions, atol=1e-6)
    assert geo.quat_angle_between(traj.orientations[1:k + 1], obs.orientations).max() < 1e-5
    assert np.allclose(traj.lin_vels[1:k + 1], obs.lin_vels, atol=1e-5)
    as_dict = pred.rollout(cloud, [0.3, 0, 0], [0, 0, 1], horizon=20, observed=vars(obs))
    assert np.allclose(as_dict.positions, traj.positions)
    free = pred.rollout(cloud, [0.3, 0, 0], [0, 0, 1], horizon=20)
    assert not np.allclose(free.positions[k + 1:], traj.positions[k + 1:])
    with pytest.raises(ValueError, match="leave nothing to predict"):
        pred.rollout(cloud, [0.3, 0, 0], [0, 0, 1], horizon=3, observed=obs)
    with pytest.raises(ValueError, match="observed lin_vels"):
        pred.rollout(cloud, [0.3, 0, 0], [0, 0, 1], horizon=20, observed=dict(vars(obs), lin_vels=np.zeros((2, 3))))


def test_resampling_any_number_of_points(pred, cloud):
    few = pred.encode(cloud[:5])  # fewer points than the model takes: repeated
    assert few.feature.shape == (8,) and np.all(np.isfinite(few.feature))
    assert np.allclose(pred.encode(cloud).feature, pred.encode(cloud).feature)  # fixed subsample


def test_cloud_files_and_predict_command(tmp_path, cloud, model_path, capsys):
    from physdyn_ros.cli import main

    np.save(tmp_path / "c.npy", cloud)
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(cloud)}\nproperty float x\n" \
             "property float y\nproperty float z\nproperty uchar red\nend_header\n"
    rows = np.zeros(len(cloud), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1")])
    rows["x"], rows["y"], rows["z"] = cloud.T
    (tmp_path / "c.ply").write_bytes(header.encode() + rows.tobytes())
    ascii_ply = f"ply\nformat ascii 1.0\nelement vertex {len(cloud)}\nproperty double x\nproperty double y\n" \
                "property double z\nend_header\n" + "\n".join(" ".join(map(str, p)) for p in cloud) + "\n"
    (tmp_path / "a.ply").write_text(ascii_ply)
    np.savetxt(tmp_path / "c.xyz", cloud)
    for name in ("c.npy", "c.ply", "a.ply", "c.xyz"):
        assert np.allclose(load_cloud(tmp_path / name), cloud, atol=1e-6), name
    with pytest.raises(ValueError, match="unsupported"):
        (tmp_path / "c.obj").write_text("v")
        load_cloud(tmp_path / "c.xyz").tolist() and load_cloud(tmp_path / "c.obj")
    code = main(["predict", "--model", str(model_path), "--cloud", str(tmp_path / "c.ply"), "--lin-vel", "0.4", "0",
                 "0", "--ang-vel", "0", "0", "1", "--horizon", "30"])
    out = capsys.readouterr().out
    assert code == 0 and "final position" in out and "topple probability" in out
    assert "(spread " in out and "with probability 0.9" not in out  # a model without a spread calibration
    code = main(["predict", "--cloud", str(tmp_path / "c.npy"), "--lin-vel", "0.4", "0", "0", "--ang-vel", "0", "0",
                 "1", "--json"])  # the shipped model has one
    spread = json.loads(capsys.readouterr().out)["spread"]
    assert code == 0 and spread["level"] == 0.9 and spread["position"] > 0 and spread["yaw"] > 0
    bad = main(["predict", "--model", str(model_path), "--cloud", str(tmp_path / "c.npy"), "--lin-vel", "0", "0",
                "0", "--ang-vel", "0", "0", "0", "--horizon", "500"])
    assert bad == 2 and "horizon must be in 1..80" in capsys.readouterr().err


def test_encode_many_equals_encoding_each_cloud(tmp_path):
    """Perception encodes every object of a cloud in one pass (encode_many): the same codes as one by one."""
    pred = Predictor.load(random_checkpoint(tmp_path / "m.pt"))
    rng = np.random.default_rng(4)
    clouds = [rng.uniform(-1, 1, (n, 3)) * s + [rng.normal() * 0.2, rng.normal() * 0.2, 0.1]
              for n, s in ((3000, (0.05, 0.03, 0.1)), (40, (0.04, 0.04, 0.05)), (700, (0.05, 0.02, 0.03)))]
    many = pred.encode_many(clouds)
    assert pred.encode_many([]) == []
    for cloud, code in zip(clouds, many):
        one = pred.encode(cloud)
        assert np.allclose(one.feature, code.feature, atol=1e-5) and np.allclose(one.centroid, code.centroid)
        assert one.heading == code.heading and np.allclose(one.half_extents, code.half_extents)
        assert one.num_points == code.num_points == len(cloud)
    with pytest.raises(ValueError):
        pred.encode_many([clouds[0], np.full((5, 3), np.nan)])
