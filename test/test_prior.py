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
"""The sliding prior: stepping it reproduces the closed-form analytic baseline; it stops exactly at rest."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from physdyn_ros.conventions import DT, GRAVITY
from physdyn_ros.learn.baselines import analytic_sliding
from physdyn_ros.learn.prior import decelerations, sliding_step


def test_stepping_the_prior_is_the_closed_form_baseline():
    rng = np.random.default_rng(0)
    b, horizon, mu = 64, 60, 0.5
    vel0 = np.column_stack([rng.normal(0, 1.0, (b, 2)), np.zeros(b)])
    angvel0 = np.column_stack([np.zeros((b, 2)), rng.normal(0, 6.0, b)])
    radius = rng.uniform(0.02, 0.2, b)
    ref = analytic_sliding(np.zeros((b, 3)), np.tile([0, 0, 0, 1.0], (b, 1)), vel0, angvel0, np.full(b, mu),
                           radius, horizon, DT)
    v, w = torch.tensor(vel0), torch.tensor(angvel0)
    decel = torch.full((b,), mu * GRAVITY, dtype=torch.float64)
    pos, yaw = torch.zeros(b, 3, dtype=torch.float64), torch.zeros(b, dtype=torch.float64)
    for t in range(horizon):
        dv, dw, dp, dr = sliding_step(v, w, decel, decel / torch.tensor(radius), torch.zeros(b, dtype=torch.float64))
        v, w, pos, yaw = v + dv, w + dw, pos + dp, yaw + dr[:, 2]
        np.testing.assert_allclose(pos.numpy(), ref["pos"][:, t + 1], atol=1e-9)
        np.testing.assert_allclose(v.numpy(), ref["lin_vel"][:, t + 1], atol=1e-9)
        np.testing.assert_allclose(w.numpy()[:, 2], ref["ang_vel"][:, t + 1, 2], atol=1e-9)
    ref_yaw = 2 * np.arctan2(ref["quat"][:, -1, 2], ref["quat"][:, -1, 3])
    np.testing.assert_allclose(np.angle(np.exp(1j * yaw.numpy())), ref_yaw, atol=1e-9)
    # at rest the prior is exactly zero: no creeping, no drift
    assert torch.all(v[:, :2].abs().sum(-1)[torch.linalg.vector_norm(torch.tensor(vel0), dim=-1) < 1.0] == 0)


def test_the_coupled_prior_shares_friction_between_sliding_and_spinning():
    """model.prior coupled: the ellipsoidal limit surface. Pure sliding and pure spinning decelerate
    as in the sliding prior; an object sliding at v while spinning at w shares the friction: the speed decreases
    by mu g v / |(v, r w)| per second, the spin by (mu g / r) r |w| / |(v, r w)| (the decoupled prior stops the
    spin of a fast-sliding object within a step). The numpy kernel's step (prior_into) is the same arithmetic."""
    from physdyn_ros.learn.prior import prior_constants, prior_into

    mu_g, r = 0.5 * GRAVITY, 0.05
    decel = torch.tensor([mu_g] * 3, dtype=torch.float64)
    spin = decel / r
    one = torch.ones(3, dtype=torch.float64)
    v = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    w = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 20.0], [0.0, 0.0, 3.2]], dtype=torch.float64)
    dv, dw, dp, dr = sliding_step(v, w, decel, spin, one)
    assert dv[0, 0].item() == pytest.approx(-mu_g * DT)  # pure sliding: mu g
    assert dw[1, 2].item() == pytest.approx(-mu_g / r * DT, rel=1e-6)  # pure spin: mu g / r
    norm = math.hypot(1.0, r * 3.2)
    assert dv[2, 0].item() == pytest.approx(-mu_g / norm * DT, rel=1e-6)
    assert dw[2, 2].item() == pytest.approx(-(mu_g / r) * (r * 3.2 / norm) * DT, rel=1e-6)
    decoupled = sliding_step(v, w, decel, spin, torch.zeros(3, dtype=torch.float64))[1]
    assert 3.2 + decoupled[2, 2].item() == 0.0 and 3.2 + dw[2, 2].item() > 2.0  # stopped vs kept turning
    # prior_into (batch-1 numpy kernel) on the same state, in identity scales
    ones = np.ones(19)
    row, x = np.zeros(19), np.array([1.0, 0.0, 0.0, 0.0, 0.0, 3.2])
    prior_into(row, x, prior_constants(mu_g, mu_g / r, ones, ones, ones, DT, coupling=1.0))
    assert row[0] == pytest.approx(dv[2, 0].item(), rel=1e-9) and row[5] == pytest.approx(dw[2, 2].item(), rel=1e-9)
    assert row[6] == pytest.approx(dp[2, 0].item(), rel=1e-9) and row[11] == pytest.approx(dr[2, 2].item(), rel=1e-9)


def test_decelerations_from_the_cloud():
    cloud = torch.tensor([[[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [0.0, -0.1, 0.05]]])
    decel, spin = decelerations(cloud, 0.5)
    assert torch.allclose(decel, torch.tensor([0.5 * GRAVITY])) and torch.allclose(spin, decel / 0.1)
    thin = torch.zeros(1, 8, 3)
    assert torch.isfinite(decelerations(thin, 0.5)[1]).all()  # a degenerate cloud: bounded, not infinite


def _hybrid(seed: int = 0, prior: str = "sliding", **extra):
    from physdyn_ros.learn.model import DynamicsModel, ModelConfig

    torch.manual_seed(seed)
    cfg = ModelConfig(name="hybrid", num_points=64, pointnet=(16, 32), shape_mlp=(16, 8), hidden_size=24,
                      num_layers=2, geometry=True, prior=prior, com_head=True, **extra)
    stats = {"vel": 0.8, "angvel": 5.0, "d_vel": 0.05, "d_angvel": 0.4, "d_pos": 0.03, "d_rot": 0.2, "cloud": 0.08}
    return DynamicsModel(cfg, stats)


def _cloud(b: int, rng: np.random.Generator) -> torch.Tensor:
    pts = rng.uniform(-1, 1, (b, 64, 3)) * rng.uniform(0.03, 0.12, (b, 1, 3))
    return torch.tensor(pts - pts.mean(1, keepdims=True), dtype=torch.float32)


def test_an_untrained_hybrid_model_is_the_analytic_baseline_in_every_kernel():
    """model.prior sliding with the zero-initialised residual: all three roll-out kernels (autograd TorchScript,
    fused batch, numpy batch 1) and teacher forcing reproduce Coulomb sliding with the cloud's lever arm."""
    rng = np.random.default_rng(1)
    model = _hybrid().eval()
    b, horizon = 5, 40
    cloud = _cloud(b, rng)
    vel0 = np.column_stack([rng.normal(0, 0.8, (b, 2)), np.zeros(b)]).astype(np.float32)
    ang0 = np.column_stack([np.zeros((b, 2)), rng.normal(0, 5.0, b)]).astype(np.float32)
    radius = np.sqrt((cloud.numpy()[..., :2] ** 2).sum(-1).mean(-1))
    ref = analytic_sliding(np.zeros((b, 3)), np.tile([0, 0, 0, 1.0], (b, 1)), vel0, ang0, np.full(b, 0.5),
                           radius, horizon, DT)
    feature = model.encode(cloud).detach()
    v0, w0 = torch.from_numpy(vel0), torch.from_numpy(ang0)
    runs = {"autograd": model.rollout_raw(feature, v0, w0, horizon)[0].detach()}  # grad on: TorchScript kernel
    with torch.inference_mode():
        runs["fused"] = model.rollout_raw(feature, v0, w0, horizon)[0]
        runs["numpy"] = torch.cat([model.rollout_raw(feature[i:i + 1], v0[i:i + 1], w0[i:i + 1], horizon)[0]
                                   for i in range(b)])
    for name, raw in runs.items():
        out = model.denormalize(raw)
        pos = out["d_pos"].cumsum(1).numpy()
        yaw = out["d_rot"][..., 2].cumsum(1).numpy()
        np.testing.assert_allclose(pos, ref["pos"][:, 1:], atol=2e-5, err_msg=name)
        ref_yaw = np.unwrap(2 * np.arctan2(ref["quat"][:, 1:, 2], ref["quat"][:, 1:, 3]), axis=1)
        np.testing.assert_allclose(yaw, ref_yaw, atol=2e-4, err_msg=name)
        assert torch.all(out["topple_logit"] == 0) and torch.all(out["d_pos"][..., 2] == 0), name
    # teacher forcing with the analytic velocities gives the same increments
    with torch.no_grad():
        tf = model.denormalize(model.teacher_forced(feature, torch.tensor(ref["lin_vel"][:, :-1], dtype=torch.float32),
                                                    torch.tensor(ref["ang_vel"][:, :-1], dtype=torch.float32)))
    np.testing.assert_allclose(tf["d_pos"].numpy(), np.diff(ref["pos"], axis=1), atol=2e-5)


def test_every_kernel_runs_the_coupled_prior_alike():
    """model.prior coupled in the three roll-out kernels (TorchScript autograd, fused batch, numpy batch 1): the
    same trajectories, and the spin of a sliding object outlasts the decoupled prior's."""
    rng = np.random.default_rng(3)
    model, plain = _hybrid(prior="coupled").eval(), _hybrid(prior="sliding").eval()
    b, horizon = 4, 30
    cloud = _cloud(b, rng)
    v0 = torch.tensor(np.column_stack([rng.uniform(0.8, 1.5, b), np.zeros((b, 2))]), dtype=torch.float32)
    w0 = torch.tensor(np.column_stack([np.zeros((b, 2)), rng.uniform(2.0, 6.0, b)]), dtype=torch.float32)
    feature = model.encode(cloud).detach()
    runs = {"autograd": model.rollout_raw(feature, v0, w0, horizon)[0].detach()}
    with torch.inference_mode():
        runs["fused"] = model.rollout_raw(feature, v0, w0, horizon)[0]
        runs["numpy"] = torch.cat([model.rollout_raw(feature[i:i + 1], v0[i:i + 1], w0[i:i + 1], horizon)[0]
                                   for i in range(b)])
        decoupled = plain.denormalize(plain.rollout_raw(feature, v0, w0, horizon)[0])
    turns = {name: model.denormalize(raw)["d_rot"][..., 2].sum(1) for name, raw in runs.items()}
    for name, turn in turns.items():
        np.testing.assert_allclose(turn.numpy(), turns["autograd"].numpy(), rtol=1e-4, err_msg=name)
    assert torch.all(turns["numpy"].abs() > 1.2 * decoupled["d_rot"][..., 2].sum(1).abs())


def test_hybrid_model_trains_and_its_com_head_learns(tmp_path):
    """A tiny hybrid model with a centre-of-mass head trains on real simulations (partial views on) and both
    losses go down."""
    from learn_support import tiny_config, tiny_dataset
    from physdyn_ros.learn.train import train

    cfg = tiny_config(model={"geometry": True, "prior": "sliding", "com_head": True},
                      data={"partial_views": 0.5}, train={"epochs": 4})
    train(cfg, tiny_dataset(), tmp_path / "run", progress=False)
    hist = [json.loads(ln) for ln in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    assert len(hist) == 4 and hist[-1]["train_com"] < 0.8 * hist[0]["train_com"], [h["train_com"] for h in hist]
    assert hist[-1]["train_total"] < hist[0]["train_total"]


def test_predictor_starts_at_the_estimated_centre_of_mass(tmp_path):
    """With a centre-of-mass head the default start is centroid + the estimate (turned into the table frame)."""
    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.learn.frames import canonicalize_cloud
    from physdyn_ros.predictor import Predictor

    model = _hybrid()
    with torch.no_grad():
        model.com.weight.zero_()
        model.com.bias.copy_(torch.tensor([0.25, -0.5, -0.125]))  # cloud-scale units: 2, -4, -1 cm
    save_checkpoint(tmp_path / "h.pt", model=model, config={"model": model.cfg.to_dict()}, dataset={},
                    include_rng=False)
    pred = Predictor.load(tmp_path / "h.pt")
    cloud = _cloud(1, np.random.default_rng(2)).numpy()[0].astype(np.float64) + (0.3, 0.1, 0.05)
    code = pred.encode(cloud)
    canon = canonicalize_cloud(cloud)
    c, s = np.cos(canon.heading), np.sin(canon.heading)
    offset = np.array([0.02, -0.04, -0.01])
    expected = canon.centroid + [c * offset[0] - s * offset[1], s * offset[0] + c * offset[1], offset[2]]
    np.testing.assert_allclose(code.centroid, expected, atol=1e-6)
    traj = pred.rollout(code, [0.3, 0.0, 0.0], [0.0, 0.0, 0.0], horizon=5)
    np.testing.assert_allclose(traj.positions[0], expected, atol=1e-6)


def test_a_predicted_object_comes_to_rest_exactly(tmp_path):
    """A network's velocities need not reach zero when its poses have stopped. After the rest rule the velocities
    are exactly zero from the first quiet state on, and the pose no longer moves."""
    from physdyn_ros.learn.checkpoint import save_checkpoint
    from physdyn_ros.predictor import Predictor, settle

    # the rule itself: a fed-back velocity offset after the poses stopped
    h = 10
    d_pos = np.zeros((1, h, 3))
    d_pos[0, :3, 0] = 0.01
    d_rot = np.zeros((1, h, 3))
    lin = np.full((1, h + 1, 3), [0.25, 0.0, 0.0])
    ang = np.zeros((1, h + 1, 3))
    rest = settle(d_pos, d_rot, lin, ang)
    assert rest[0] == 4 and np.all(lin[0, 4:] == 0) and np.all(lin[0, :4, 0] == 0.25)
    assert np.all(d_pos[0, :3, 0] == 0.01) and np.all(d_pos[0, 3:] == 0)
    # through the Predictor, with a model: a slow push stops and stays stopped
    model = _hybrid()
    save_checkpoint(tmp_path / "h.pt", model=model, config={"model": model.cfg.to_dict()}, dataset={},
                    include_rng=False)
    pred = Predictor.load(tmp_path / "h.pt")
    cloud = _cloud(1, np.random.default_rng(3)).numpy()[0].astype(np.float64) + (0.0, 0.0, 0.05)
    traj = pred.rollout(cloud, [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], horizon=60)
    stopped = np.flatnonzero(np.all(traj.lin_vels == 0, axis=1) & np.all(traj.ang_vels == 0, axis=1))
    assert len(stopped) and stopped[0] < 20  # 0.5 m/s at mu 0.5 stops after 0.1 s
    assert np.all(traj.positions[stopped[0]:] == traj.positions[stopped[0]])
    slide = np.linalg.norm(traj.positions[-1, :2] - traj.positions[0, :2])
    assert abs(slide - 0.5 ** 2 / (2 * 0.5 * 9.81)) < 0.002  # Coulomb: v^2 / (2 mu g) = 2.55 cm


def test_topple_probability_agrees_with_the_predicted_poses():
    """The probability agrees with the model's own poses: it never decreases, and it is 1 once the predicted pose
    has tilted past 45 degrees."""
    from scipy.spatial.transform import Rotation

    from physdyn_ros.predictor import consistent_topple

    tilt = np.radians([0, 10, 30, 50, 80, 80])
    quats = Rotation.from_rotvec(np.column_stack([tilt, 0 * tilt, 0 * tilt])).as_quat()[None]
    prob = np.array([[0.0, 0.3, 0.1, 0.2, 0.05, 0.0]])
    assert consistent_topple(prob, quats).tolist() == [[0.0, 0.3, 0.3, 1.0, 1.0, 1.0]]
    upright = np.tile([0, 0, 0, 1.0], (1, 6, 1))
    assert consistent_topple(prob, upright).tolist() == [[0.0, 0.3, 0.3, 0.3, 0.3, 0.3]]


def test_degenerate_and_out_of_range_clouds_are_refused(tmp_path):
    """One point repeated or a line of points is no object: refused, not given a confident trajectory."""
    import pytest

    from physdyn_ros.predictor import check_cloud

    rng = np.random.default_rng(0)
    box = rng.uniform(-1, 1, (500, 3)) * (0.05, 0.03, 0.04)
    assert check_cloud(box).shape == (500, 3)
    with pytest.raises(ValueError, match="degenerate"):
        check_cloud(np.tile([0.1, 0.2, 0.03], (300, 1)))
    with pytest.raises(ValueError, match="degenerate"):
        check_cloud(np.outer(np.linspace(0, 0.2, 100), [1.0, 0.5, 0.0]))  # a line
    with pytest.raises(ValueError, match="larger than any trained object"):
        check_cloud(box * 40)
    flat_but_wide = box * (1, 1, 0)  # a sheet: a real table-top object's visible top face, kept
    assert check_cloud(flat_but_wide).shape == (500, 3)


def test_no_phantom_tilt_unless_the_model_predicts_a_topple():
    """Objects that slide flat keep no predicted tilt unless the model predicts a topple."""
    from physdyn_ros.learn.rules import flat_unless_toppling

    d_rot = np.tile([0.02, -0.01, 0.1], (2, 4, 1))
    ang = np.tile([0.3, -0.2, 1.5], (2, 5, 1))
    prob = np.array([[0.0, 0.1, 0.2, 0.1, 0.1], [0.0, 0.2, 0.7, 0.9, 0.9]])
    toppling = flat_unless_toppling(d_rot, ang, prob)
    assert toppling.tolist() == [False, True]
    assert np.all(d_rot[0, :, :2] == 0) and np.all(d_rot[0, :, 2] == 0.1)  # yaw kept, tilt gone
    assert np.all(ang[0, 0] == [0.3, -0.2, 1.5]) and np.all(ang[0, 1:, :2] == 0)  # the given state untouched
    assert np.all(d_rot[1, :, 0] == 0.02)  # a toppling trajectory keeps its tilt
