"""The spin head (learn/spin.py, `physdyn fit-spin`): a per-push factor on the roll-out's change of spin about z."""
from __future__ import annotations

import argparse

import numpy as np
import pytest
import torch
from learn_support import tiny_config, tiny_dataset

from physdyn_ros import geometry as geo
from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig

STATS = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))
ARCH = dict(num_points=64, pointnet=(32, 64), shape_mlp=(32, 8), hidden_size=32, geometry=True, prior="coupled",
            input_skip=True)


def _models(seed: int = 0) -> tuple[DynamicsModel, DynamicsModel]:
    """The same random network without and with a spin head (fresh: factor 1)."""
    torch.manual_seed(seed)
    plain = DynamicsModel(ModelConfig(**ARCH), STATS).eval()
    with torch.no_grad():  # a non-zero residual, so the network's own spin change is scaled too
        torch.nn.init.normal_(plain.head.weight, std=0.05)
    headed = DynamicsModel(ModelConfig(**ARCH, spin_head=True), STATS).eval()
    missing = headed.load_state_dict(plain.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith("spin.") for k in missing)
    return plain, headed


def _inputs(model: DynamicsModel, batch: int, seed: int = 1):
    g = torch.Generator().manual_seed(seed)
    feature = torch.cat([torch.randn(batch, 8, generator=g), torch.rand(batch, model.feature_dim - 8, generator=g)
                         + 0.5], 1)
    v = torch.randn(batch, 3, generator=g) * torch.tensor([1.0, 1.0, 0.1])
    w = torch.randn(batch, 3, generator=g) * torch.tensor([1.0, 1.0, 6.0])
    return feature, v, w


def test_a_fresh_spin_head_changes_nothing_and_every_kernel_applies_a_fitted_one():
    plain, headed = _models()
    feature, v, w = _inputs(plain, 6)
    with torch.inference_mode():
        for b in (1, 6):  # 1: the batch-1 numpy kernel (rollout_arrays); 6: the fused torch kernel
            a = plain.rollout_arrays(feature[:b].numpy(), v[:b].numpy(), w[:b].numpy(), 40)[0]
            h = headed.rollout_arrays(feature[:b].numpy(), v[:b].numpy(), w[:b].numpy(), 40)[0]
            assert np.array_equal(a, h)  # factor exactly 1
    with torch.no_grad():
        for p in headed.spin.parameters():
            torch.nn.init.normal_(p, std=0.3)
        torch.nn.init.normal_(headed.spin.net[-1].weight, std=0.05)  # factors of about 0.6-1.6: none clipped
    k = headed.spin.factor(feature.numpy(), v.numpy(), w.numpy())
    assert np.ptp(k) > 0.05 and np.all((k >= 0.25) & (k <= 2.0))
    assert np.allclose(headed.spin(feature, v, w).detach().numpy(), k, rtol=1e-5)  # torch and numpy agree
    with torch.inference_mode():
        ref_raw, ref_xs = plain.rollout_raw(feature, v, w, 40, spin_scale=torch.from_numpy(k).float())
        raw, xs = headed.rollout_raw(feature, v, w, 40)
        assert torch.allclose(raw, ref_raw, atol=2e-5) and torch.allclose(xs, ref_xs, atol=2e-5)
        for i in range(6):  # one push at a time: the numpy kernel with the head's factor in numpy
            one, xs1, _ = headed.rollout_arrays(feature[i:i + 1].numpy(), v[i:i + 1].numpy(), w[i:i + 1].numpy(), 40)
            scale = max(float(ref_raw.abs().max()), 1.0)
            assert np.abs(one[0] - ref_raw[i].numpy()).max() < 2e-5 * scale, i
            assert np.abs(xs1[0] - ref_xs[i].numpy()).max() < 2e-5 * max(float(ref_xs.abs().max()), 1.0), i
        # a given spin_scale replaces the head's
        ones = headed.rollout_raw(feature, v, w, 40, spin_scale=torch.ones(6))[0]
        assert torch.allclose(ones, plain.rollout_raw(feature, v, w, 40)[0], atol=1e-6)
    with torch.enable_grad():  # the differentiable kernel applies it too
        grad_raw = headed.rollout_raw(feature, v, w, 40)[0]
    assert torch.allclose(grad_raw.detach(), ref_raw, atol=2e-5)
    # the spin's sense does not matter: mirrored pushes get the same factor
    mirror = torch.tensor([1.0, -1.0, 1.0])
    assert np.allclose(headed.spin.factor(feature.numpy(), (v * mirror).numpy(), (w * -mirror).numpy()), k)


def test_a_spin_head_needs_the_prior():
    with pytest.raises(ValueError, match="spin_head .* needs model.prior"):
        ModelConfig(num_points=64, pointnet=(32, 64), shape_mlp=(32, 8), spin_head=True)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A tiny model that is exactly the coupled prior (zero residual) with its spin head fitted by `physdyn
    fit-spin` on the tiny dataset."""
    from physdyn_ros.learn import spin_fit
    from physdyn_ros.learn.checkpoint import save_checkpoint

    tmp = tmp_path_factory.mktemp("spin")
    cfg = tiny_config(model={"geometry": True, "prior": "coupled"})
    torch.manual_seed(0)
    model = DynamicsModel(ModelConfig.from_dict(cfg["model"]), STATS)
    src = tmp / "src.pt"
    save_checkpoint(src, model=model, config=cfg, dataset={}, include_rng=False)
    out = tmp / "fitted.pt"
    args = argparse.Namespace(checkpoint=str(src), data=[str(tiny_dataset())], out=str(out), max_train=60, max_val=20,
                              partial=0.5, epochs=40, seed=0, threads=1, position_weight=1.0)
    assert spin_fit.run(args) == 0
    return src, out


def test_fit_spin_lowers_the_validation_error_and_the_predictor_applies_the_head(fitted):
    from physdyn_ros.learn.checkpoint import load_model, save_checkpoint
    from physdyn_ros.predictor import Predictor

    src, out = fitted
    model, ckpt = load_model(out)
    fit = ckpt["config"]["spin_fit"]["validation"]
    # the tiny dataset's training pushes that do not topple (fewer than 60), and its validation ones
    assert model.spin is not None and 20 < fit["train_pushes"] <= 60 and 0 < fit["val_pushes"] <= 20
    assert fit["val_loss"] <= fit["val_loss_k1"]  # epoch 0 (k = 1) is a candidate: never worse than no head
    assert torch.all(model.spin.std > 0)  # standardised on the data
    # 46 pushes teach this head little: give it a clear factor to check that the Predictor applies it
    with torch.no_grad():
        model.spin.net[-1].bias.fill_(float(np.log(0.5)))
    save_checkpoint(out, model=model, config=ckpt["config"], dataset={}, include_rng=False)
    plain, headed = Predictor.load(src), Predictor.load(out)
    assert headed.model_id != plain.model_id
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(400, 3)) * [0.04, 0.03, 0.05] + [0.2, 0.0, 0.05]
    code = headed.encode(cloud)
    v, w = np.array([0.3, 0.1, 0.0]), np.array([0.0, 0.0, 8.0])
    traj, base = headed.rollout(code, v, w, 30), plain.rollout(plain.encode(cloud), v, w, 30)
    feature = code.feature[None, :headed._dynamics_dim]
    k = float(model.spin.factor(feature, geo.rotate_yaw(v, -code.heading)[None],
                                geo.rotate_yaw(w, -code.heading)[None])[0])
    assert 0.3 < k < 0.8
    # the prior's spin: |w_z| falls by k alpha per step while spinning (alpha read off the plain model's first step)
    alpha = w[2] - base.ang_vels[1, 2]
    assert alpha > 0
    assert traj.ang_vels[1, 2] == pytest.approx(w[2] - k * alpha, rel=1e-3, abs=1e-4)


def test_the_fit_recovers_a_factor_that_depends_on_the_inputs():
    """_train on synthetic error curves whose best factor is exp(0.5 x_0) (x_0 one standardised input): the head
    finds it, and its validation loss falls well below k = 1's."""
    from physdyn_ros.learn.spin import SpinHead
    from physdyn_ros.learn.spin_fit import GRID, _train

    rng = np.random.default_rng(0)
    head = SpinHead(feature_dim=5)
    x = rng.normal(size=(1500, head.in_dim)).astype(np.float32)
    best = np.clip(0.5 * x[:, 0], np.log(GRID[0]), np.log(GRID[-1]))
    curves = 20.0 * np.abs(np.log(GRID)[None, :] - best[:, None])  # degrees, V-shaped around the best factor
    result = _train(head, x[:1200], curves[:1200], x[1200:], curves[1200:], epochs=30, lr=3e-3, weight_decay=0.0,
                    seed=0, log=None)
    assert result["val_loss"] < 0.5 * result["val_loss_k1"]
    with torch.no_grad():
        got = head.log_factor(torch.from_numpy(x[1200:])).numpy()
    assert np.corrcoef(got, best[1200:])[0, 1] > 0.9
