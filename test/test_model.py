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
"""The network and the learning frame: output shapes, the compiled roll-out, exact yaw/translation equivariance."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from learn_support import random_checkpoint, tiny_dataset
from physdyn_ros import geometry as geo
from physdyn_ros.learn import frames
from physdyn_ros.learn.model import OUT_DIM, STAT_KEYS, DynamicsModel, ModelConfig, count_parameters

STATS = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))


def tiny_model(cell: str = "lstm", norm: str = "layer", skip: bool = False) -> DynamicsModel:
    torch.manual_seed(0)
    cfg = ModelConfig(num_points=64, pointnet=(32, 64), shape_mlp=(32, 8), hidden_size=32, cell=cell, norm=norm,
                      input_skip=skip)
    m = DynamicsModel(cfg, STATS).eval()
    if skip:  # it starts at zero; give it weights so that the tests see the path
        torch.nn.init.normal_(m.skip.weight)
    return m


@pytest.mark.parametrize("cell", ["lstm", "mlp"])
@pytest.mark.parametrize("norm", ["layer", "batch"])
def test_output_shapes(cell, norm):
    m = tiny_model(cell, norm)
    cloud, vel, ang = torch.randn(3, 64, 3) * 0.1, torch.randn(3, 12, 3), torch.randn(3, 12, 3)
    with torch.no_grad():
        feat = m.encode(cloud)
        assert feat.shape == (3, 8)
        assert m.teacher_forced(feat, vel, ang).shape == (3, 12, OUT_DIM)
        out = m.rollout(feat, vel[:, 0], ang[:, 0], 20)
    assert out["vel"].shape == out["angvel"].shape == (3, 21, 3)
    assert out["d_pos"].shape == out["d_rot"].shape == out["d_vel"].shape == (3, 20, 3)
    assert out["topple_logit"].shape == (3, 20)
    m.train()
    assert m(cloud, vel, ang).shape == (3, 11, OUT_DIM)
    assert m(cloud, vel, ang, feedback=True).shape == (3, 11, OUT_DIM)


def test_paper_configuration_size():
    import yaml

    from conftest import ROOT
    from physdyn_ros.learn.config import resolve_config

    cfg = resolve_config(yaml.safe_load((ROOT / "config" / "model_paper.yaml").read_text()))["model"]
    m = DynamicsModel(ModelConfig.from_dict(cfg))
    n = count_parameters(m)
    assert m.feature_dim == 16 and cfg["hidden_size"] == 1024 and cfg["num_layers"] == 3
    assert 20e6 < n["total"] < 26e6  # ~22.9 M in the original
    assert n["lstm"] == 4 * 1024 * (22 + 1024 + 2) + 2 * 4 * 1024 * (1024 + 1024 + 2)


@pytest.mark.parametrize("cell", ["lstm", "mlp"])
@pytest.mark.parametrize("skip", [False, True])
def test_compiled_rollout_equals_teacher_forcing_on_its_own_inputs(cell, skip):
    m = tiny_model(cell, skip=skip)
    with torch.no_grad():
        feat = m.encode(torch.randn(4, 64, 3) * 0.1)
        out = m.rollout(feat, torch.randn(4, 3), torch.randn(4, 3), 25)
        raw = m.teacher_forced(feat, out["vel"][:, :-1], out["angvel"][:, :-1])
    again = m.denormalize(raw)
    for k in ("d_vel", "d_angvel", "d_pos", "d_rot", "topple_logit"):
        assert torch.allclose(again[k], out[k], atol=1e-5), k
    # fed back: v_{t+1} = v_t + d_vel_t
    assert torch.allclose(out["vel"][:, 1:], out["vel"][:, :-1] + out["d_vel"], atol=1e-5)


def test_input_skip_starts_as_the_plain_network_and_is_linear_in_the_input():
    plain = tiny_model()
    skip = DynamicsModel(ModelConfig(**{**plain.cfg.to_dict(), "input_skip": True}), STATS).eval()
    skip.load_state_dict({**plain.state_dict(), "skip.weight": torch.zeros(OUT_DIM, 6)})
    feat, vel, ang = torch.randn(2, 8), torch.randn(2, 5, 3), torch.randn(2, 5, 3)
    with torch.no_grad():
        assert torch.equal(plain.teacher_forced(feat, vel, ang), skip.teacher_forced(feat, vel, ang))
        skip.skip.weight.fill_(0.5)
        delta = skip.teacher_forced(feat, vel, ang) - plain.teacher_forced(feat, vel, ang)
    x = torch.cat([vel / STATS["vel"], ang / STATS["angvel"]], -1)
    assert torch.allclose(delta, 0.5 * x.sum(-1, keepdim=True).expand_as(delta), atol=1e-5)
    assert tiny_model().skip is None and "skip.weight" not in tiny_model().state_dict()


def test_steps_in_feeds_the_observed_velocities():
    m = tiny_model()
    obs_v, obs_w = torch.randn(2, 4, 3), torch.randn(2, 4, 3)
    with torch.no_grad():
        feat = m.encode(torch.randn(2, 64, 3) * 0.1)
        out = m.rollout(feat, torch.randn(2, 3), torch.randn(2, 3), 10, obs_v, obs_w)
    assert torch.allclose(out["vel"][:, 1:5], obs_v, atol=1e-6)
    assert torch.allclose(out["angvel"][:, 1:5], obs_w, atol=1e-6)


def test_rollout_is_differentiable_for_closed_loop_training():
    m = tiny_model()
    m.train()
    out = m(torch.randn(2, 64, 3) * 0.1, torch.randn(2, 8, 3), torch.randn(2, 8, 3), feedback=True)
    out.square().sum().backward()
    assert all(torch.all(torch.isfinite(p.grad)) for p in m.lstm.parameters())
    assert m.lstm.weight_hh_l0.grad.abs().sum() > 0


def test_canonical_heading_is_yaw_equivariant():
    rng = np.random.default_rng(0)
    for trial in range(60):
        cloud = rng.normal(size=(300, 3)) * rng.uniform(0.05, 0.3, 3)
        if trial % 3 == 0:  # near-isotropic horizontally: exercises the fallback
            cloud[:, 1] = cloud[:, 0].std() / cloud[:, 1].std() * cloud[:, 1] * rng.uniform(0.98, 1.02)
        psi = rng.uniform(-np.pi, np.pi)
        moved = geo.rotate_yaw(cloud, psi) + rng.normal(size=3)
        d = geo.canonical_heading(moved) - geo.canonical_heading(cloud) - psi
        assert abs(np.angle(np.exp(1j * d))) < 1e-9
    batch = rng.normal(size=(5, 100, 3))
    assert np.allclose(geo.canonical_heading(batch), [geo.canonical_heading(c) for c in batch])
    for bad in (np.zeros((0, 3)), np.zeros((4, 2)), np.full((3, 3), np.nan)):
        with pytest.raises(ValueError):
            geo.canonical_heading(bad)


def test_rotation_helpers_round_trip():
    rng = np.random.default_rng(1)
    q = geo.quat_normalize(rng.normal(size=(50, 4)))
    assert np.allclose(np.abs(np.sum(geo.axis_angle_to_quat(geo.quat_to_axis_angle(q)) * q, -1)), 1)
    assert np.allclose(np.abs(np.sum(geo.matrix_to_quat(geo.quat_to_matrix(q)) * q, -1)), 1)
    v = rng.normal(size=(50, 3))
    assert np.allclose(geo.quat_rotate(q, v), np.einsum("nij,nj->ni", geo.quat_to_matrix(q), v))
    assert np.allclose(geo.quat_multiply(q, geo.quat_inverse(q)), [0, 0, 0, 1])
    assert np.allclose(geo.axis_angle_to_matrix(v), geo.quat_to_matrix(geo.axis_angle_to_quat(v)))
    d = geo.quat_normalize(rng.normal(size=(9, 4)))
    seq = [q[0]]
    for t in range(9):
        seq.append(geo.quat_multiply(d[t], seq[-1]))
    assert np.allclose(np.abs(np.sum(geo.quat_compose_scan(d, q[0]) * np.array(seq), -1)), 1)
    assert np.allclose(geo.rotate_yaw(v, 0.4), v @ geo.yaw_matrix(0.4).T)


def test_predictor_is_equivariant_to_yaw_and_horizontal_translation(tmp_path):
    """Property: rotate cloud + velocities by psi about z and translate; outputs rotate/translate (1e-4)."""
    from physdyn_ros.predictor import Predictor

    pred = Predictor.load(random_checkpoint(tmp_path / "m.pt"))
    rng = np.random.default_rng(2)
    for _ in range(10):
        cloud = rng.normal(size=(rng.integers(40, 400), 3)) * rng.uniform(0.02, 0.08, 3) + [0, 0, 0.1]  # <= 60 cm
        v, w = rng.normal(size=3), rng.normal(size=3) * 3
        psi, shift = rng.uniform(-np.pi, np.pi), np.array([*rng.normal(size=2) * 2, 0.0])
        q0 = geo.quat_normalize(rng.normal(size=4))
        a = pred.rollout(cloud, v, w, 40, orientation=q0)
        b = pred.rollout(geo.rotate_yaw(cloud, psi) + shift, geo.rotate_yaw(v, psi), geo.rotate_yaw(w, psi), 40,
                         orientation=geo.quat_multiply(geo.yaw_quat(psi), q0))
        assert np.abs(geo.rotate_yaw(a.positions, psi) + shift - b.positions).max() < 1e-4
        assert np.abs(geo.rotate_yaw(a.lin_vels, psi) - b.lin_vels).max() < 1e-4
        assert np.abs(geo.rotate_yaw(a.ang_vels, psi) - b.ang_vels).max() < 1e-4
        rotated = geo.quat_multiply(geo.yaw_quat(psi), a.orientations)
        assert geo.quat_angle_between(rotated, b.orientations).max() < 1e-4
        assert np.abs(a.topple_prob - b.topple_prob).max() < 1e-4


def test_training_windows_are_invariant_to_rotating_and_moving_the_whole_simulation():
    """The network input and targets of a simulation rotated by psi about z and translated are unchanged."""
    from physdyn_ros.learn.windows import load_sims, make_windows

    sims = load_sims(tiny_dataset(), ["train"]).subset(np.arange(8))
    psi, shift = 1.1, np.array([0.7, -2.0, 0.0], dtype=np.float32)
    moved = sims.subset(np.arange(8))
    moved.pos = (geo.rotate_yaw(sims.pos, psi) + shift).astype(np.float32)
    moved.lin_vel = geo.rotate_yaw(sims.lin_vel, psi).astype(np.float32)
    moved.ang_vel = geo.rotate_yaw(sims.ang_vel, psi).astype(np.float32)
    moved.quat = geo.quat_multiply(geo.yaw_quat(psi), sims.quat).astype(np.float32)
    idx, starts = np.arange(8), np.array([0, 1, 2, 3, 0, 1, 2, 3])
    a = make_windows(sims, idx, starts, 10, 64)
    b = make_windows(moved, idx, starts, 10, 64)
    for k in ("cloud", "vel", "angvel", "d_vel", "d_angvel", "d_pos", "d_rot", "topple"):
        assert torch.allclose(a[k], b[k], atol=2e-5), k
    turned = np.angle(np.exp(1j * (b["heading"].numpy() - a["heading"].numpy() - psi)))
    assert np.abs(turned).max() < 1e-5


def test_training_windows_start_while_the_object_moves():
    """random_starts: uniform in [0, min(length - 1, T - window)], so that a window never starts in the rest
    padding after a simulation ended (nor runs past its last frame)."""
    from physdyn_ros.learn.windows import load_sims, random_starts

    sims = load_sims(tiny_dataset(), ["train"])
    idx = np.repeat(np.arange(len(sims)), 20)
    starts = random_starts(sims, idx, 10, np.random.default_rng(3))
    hi = np.minimum(np.maximum(sims.length[idx] - 1, 0), sims.num_frames - 10)
    assert np.all(starts >= 0) and np.all(starts <= hi) and (starts > 0).mean() > 0.8
    assert np.any(starts == hi)  # the whole range is drawn
    np.testing.assert_array_equal(random_starts(sims, idx, 10, np.random.default_rng(3)), starts)
    with pytest.raises(ValueError, match="windows need"):
        random_starts(sims, idx, sims.num_frames + 1, np.random.default_rng(0))


def test_rotation_increments_are_world_fixed():
    """d_rot_t = log(q_{t+1} q_t^-1) matches omega * dt (world frame), as the model's convention says."""
    from physdyn_ros.learn.windows import load_sims

    sims = load_sims(tiny_dataset(), ["train"])
    inc = frames.world_increments(sims.pos, sims.quat, sims.lin_vel, sims.ang_vel)
    approx = 0.5 * (sims.ang_vel[:, 1:] + sims.ang_vel[:, :-1]) * sims.dt
    moving = (np.arange(sims.num_frames - 1)[None] < sims.length[:, None] - 1) & (
        np.linalg.norm(inc["d_rot"], axis=-1) > 0.05)
    rel = np.linalg.norm(inc["d_rot"] - approx, axis=-1)[moving] / np.linalg.norm(inc["d_rot"], axis=-1)[moving]
    assert np.median(rel) < 0.2


def test_removed_options_load_at_their_off_values_and_are_refused_when_on(tmp_path):
    """A checkpoint names every option of the code that wrote it: a removed option (learn/sections.RETIRED) at
    its off value is dropped and the checkpoint loads unchanged; switched on, loading and training refuse it by
    name."""
    import copy

    from physdyn_ros.learn.checkpoint import CheckpointError, load_model
    from physdyn_ros.learn.sections import ANY, RETIRED
    from physdyn_ros.learn.config import resolve_config

    path = random_checkpoint(tmp_path / "new.pt")
    ckpt = torch.load(path, weights_only=True)
    want, _ = load_model(path)
    for (section, key), (off, _, only_with) in RETIRED.items():
        old = copy.deepcopy(ckpt)
        old["config"][section][key] = 3 if off is ANY else off
        torch.save(old, tmp_path / "old.pt")
        model, _ = load_model(tmp_path / "old.pt")
        assert model.cfg == want.cfg and resolve_config(old["config"]) == resolve_config(ckpt["config"]), key
        if off is ANY:
            continue
        old["config"][section][key] = True if isinstance(off, bool) else off + 1
        if only_with is not None:  # it mattered only with `only_with` on: any value loads without it
            assert resolve_config(old["config"]) == resolve_config(ckpt["config"]), key
            old["config"][section][only_with] = True
        with pytest.raises(ValueError, match=f"{section}.{key} = .* needs"):
            resolve_config(old["config"])
        if section == "model":
            torch.save(old, tmp_path / "on.pt")
            with pytest.raises(CheckpointError, match=f"model.{key} = .* needs"):
                load_model(tmp_path / "on.pt")
