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
"""The relative losses: finite at zero, zero when exact, finite gradients, the paper's weighting."""
from __future__ import annotations

import pytest
import torch

from physdyn_ros.learn.losses import LossConfig, dynamics_loss, relative_l1, relative_l2, safe_l2


def _batch(seed: int = 0, b: int = 4, t: int = 6) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    raw = torch.randn(b, t, 13, generator=g)
    target = torch.randn(b, t, 12, generator=g)
    topple = (torch.rand(b, t, generator=g) > 0.5).float()
    return raw, target, topple


@pytest.mark.parametrize("fn", [relative_l2, relative_l1])
def test_zero_target_and_zero_prediction_give_zero_not_nan(fn):
    zero = torch.zeros(5, 3, requires_grad=True)
    loss = fn(zero, torch.zeros(5, 3), 1e-3)
    assert torch.all(loss == 0)
    loss.sum().backward()
    assert torch.all(torch.isfinite(zero.grad))


@pytest.mark.parametrize("fn", [relative_l2, relative_l1])
def test_zero_target_nonzero_prediction_is_finite_and_bounded(fn):
    pred = torch.tensor([[1e-6, 0.0, 0.0], [0.3, -0.2, 0.1], [1e3, 0, 0]], requires_grad=True)
    loss = fn(pred, torch.zeros(3, 3), 1e-3)
    assert torch.all(torch.isfinite(loss)) and torch.all(loss <= 1) and torch.all(loss > 0)
    loss.sum().backward()
    assert torch.all(torch.isfinite(pred.grad))


def test_identical_prediction_and_target_give_zero_loss_and_finite_gradient():
    raw, target, topple = _batch()
    raw = raw.clone()
    raw[..., :12] = target
    raw.requires_grad_(True)
    total, parts = dynamics_loss(raw, target, topple, LossConfig())
    for k in ("vel", "angvel", "pos", "rot"):
        assert parts[k].item() == 0.0
    total.backward()
    assert torch.all(torch.isfinite(raw.grad))
    assert torch.all(raw.grad[..., :12] == 0)  # the norm's subgradient at 0 is 0


def test_safe_norm_gradient_at_zero():
    x = torch.zeros(2, 3, requires_grad=True)
    safe_l2(x).sum().backward()
    assert torch.equal(x.grad, torch.zeros(2, 3))


def test_relative_loss_is_scale_invariant_away_from_eps():
    raw, target, _ = _batch(1)
    a = relative_l2(raw[..., :3], target[..., :3], 1e-9)
    b = relative_l2(100 * raw[..., :3], 100 * target[..., :3], 1e-9)
    assert torch.allclose(a, b, atol=1e-6)


def test_total_is_the_weighted_sum_with_topple_weight_two():
    raw, target, topple = _batch(2)
    cfg = LossConfig()
    assert cfg.w_topple == 2.0 and cfg.w_vel == cfg.w_angvel == cfg.w_pos == cfg.w_rot == 1.0
    total, parts = dynamics_loss(raw, target, topple, cfg)
    expected = parts["vel"] + parts["angvel"] + parts["pos"] + parts["rot"] + 2 * parts["topple"]
    assert torch.isclose(total.detach(), expected)
    bce = torch.nn.functional.binary_cross_entropy_with_logits(raw[..., 12], topple)
    assert torch.isclose(parts["topple"], bce)


def test_rotation_uses_l1_and_velocities_l2():
    pred = torch.tensor([[1.0, 1.0, 0.0]])
    target = torch.tensor([[1.0, 0.0, 0.0]])
    assert torch.isclose(relative_l1(pred, target, 0.0), torch.tensor([1.0 / 3.0]))
    assert torch.isclose(relative_l2(pred, target, 0.0), torch.tensor([1.0 / (2 ** 0.5 + 1.0)]))


def test_mask_drops_steps():
    raw, target, topple = _batch(3)
    mask = torch.zeros(raw.shape[:2])
    mask[:, :2] = 1
    _, masked = dynamics_loss(raw, target, topple, LossConfig(), mask)
    _, first = dynamics_loss(raw[:, :2], target[:, :2], topple[:, :2], LossConfig())
    assert torch.isclose(masked["total"], first["total"])


def test_bad_shapes_and_config_are_rejected():
    raw, target, topple = _batch()
    with pytest.raises(ValueError, match="loss shapes"):
        dynamics_loss(raw[..., :12], target, topple, LossConfig())
    with pytest.raises(ValueError, match="eps"):
        LossConfig.from_dict({"eps": 0})
    with pytest.raises(ValueError, match="unknown loss config"):
        LossConfig.from_dict({"w_speed": 1})


def test_target_relative_loss_pulls_a_resting_prediction_to_zero():
    """At a zero target the symmetric form saturates (no gradient); the paper's form keeps pulling to rest."""
    import torch

    from physdyn_ros.learn.losses import LossConfig, dynamics_loss

    target = torch.zeros(1, 4, 12)
    topple = torch.zeros(1, 4)
    grads = {}
    for form in ("both", "target"):
        raw = torch.full((1, 4, 13), 0.5, requires_grad=True)
        loss, parts = dynamics_loss(raw, target, topple, LossConfig(eps=0.1, relative_to=form))
        loss.backward()
        grads[form] = raw.grad[..., :12].abs().max().item()
        if form == "target":  # ||x_hat|| / eps per component
            assert parts["vel"].item() == pytest.approx((0.5 * 3 ** 0.5) / 0.1, rel=1e-5)
    assert grads["target"] > 20 * grads["both"]
    with pytest.raises(ValueError, match="relative_to"):
        LossConfig.from_dict({"relative_to": "pred"})


def assert_optional_term(raw: torch.Tensor, target: torch.Tensor, name: str, weight: float, mean: float) -> None:
    """Loss term `name` (weight w_<name>): absent by default, its per-step mean `mean`, added to the total with its
    weight; a negative weight refused."""
    topple = torch.zeros(raw.shape[:-1])
    base, parts = dynamics_loss(raw, target, topple, LossConfig(relative_to="target", eps=0.1))
    assert name not in parts
    total, parts = dynamics_loss(raw, target, topple, LossConfig(relative_to="target", eps=0.1,
                                                                 **{f"w_{name}": weight}))
    assert parts[name].item() == pytest.approx(mean)
    assert total.item() == pytest.approx(base.item() + weight * mean)
    with pytest.raises(ValueError):
        LossConfig.from_dict({f"w_{name}": -1})


def test_absolute_term_adds_the_normalised_error_and_is_off_by_default():
    raw, target = torch.zeros(1, 2, 13), torch.zeros(1, 2, 12)
    target[0, 0, 6:9] = torch.tensor([3.0, 4.0, 0.0])  # |d_pos error| = 5
    target[0, 1, 9:12] = torch.tensor([1.0, -1.0, 0.0])  # L1 rot error = 2
    assert_optional_term(raw, target, "abs", 0.5, (5.0 + 2.0) / 2)
