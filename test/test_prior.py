"""The sliding prior: stepping it reproduces the closed-form analytic baseline; it stops exactly at rest."""
from __future__ import annotations

import numpy as np
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
        dv, dw, dp, dr = sliding_step(v, w, decel, decel / torch.tensor(radius))
        v, w, pos, yaw = v + dv, w + dw, pos + dp, yaw + dr[:, 2]
        np.testing.assert_allclose(pos.numpy(), ref["pos"][:, t + 1], atol=1e-9)
        np.testing.assert_allclose(v.numpy(), ref["lin_vel"][:, t + 1], atol=1e-9)
        np.testing.assert_allclose(w.numpy()[:, 2], ref["ang_vel"][:, t + 1, 2], atol=1e-9)
    ref_yaw = 2 * np.arctan2(ref["quat"][:, -1, 2], ref["quat"][:, -1, 3])
    np.testing.assert_allclose(np.angle(np.exp(1j * yaw.numpy())), ref_yaw, atol=1e-9)
    # at rest the prior is exactly zero: no creeping, no drift
    assert torch.all(v[:, :2].abs().sum(-1)[torch.linalg.vector_norm(torch.tensor(vel0), dim=-1) < 1.0] == 0)


def test_decelerations_from_the_cloud():
    cloud = torch.tensor([[[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.1, 0.05], [0.0, -0.1, 0.05]]])
    decel, spin = decelerations(cloud, 0.5)
    assert torch.allclose(decel, torch.tensor([0.5 * GRAVITY])) and torch.allclose(spin, decel / 0.1)
    thin = torch.zeros(1, 8, 3)
    assert torch.isfinite(decelerations(thin, 0.5)[1]).all()  # a degenerate cloud: bounded, not infinite
