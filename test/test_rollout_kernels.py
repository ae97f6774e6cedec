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
"""The roll-out kernels (learn/kernels.py) compute one function.

DynamicsModel.rollout_raw runs a roll-out without autograd in fused_lstm_rollout (TorchScript, one product per layer,
sigmoid only) or, at batch 1 on the CPU, numpy_lstm_rollout; with autograd it runs lstm_rollout. The references
here are the straightforward computations: `old_rollout_raw` below (rollout_raw with lstm_rollout for every
roll-out), the teacher-forced nn.LSTM on the roll-out's own inputs, and `old_predictor_run` (the Predictor's
roll-out in torch + learn.frames.integrate_in_world).

Tolerance: float32 rounding. Reordering the sums of a 60-step closed-loop roll-out moves outputs by up to ~1e-5 of
their largest magnitude (the previous kernel itself differs by that much between a batch and its rows one at a
time), so the bound is 2e-5 of each tensor's largest magnitude; one step (teacher forcing) agrees to 1e-5.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdyn_ros import geometry as geo
from physdyn_ros.learn import kernels
from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig

FIXTURE = Path(__file__).parent / "fixtures" / "regression_set.npz"
STATS = dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))
REL = 2e-5


def old_rollout_raw(m: DynamicsModel, feature, vel0, angvel0, steps, obs_vel=None, obs_angvel=None):
    """rollout_raw of the LSTM with lstm_rollout for every roll-out (with the sliding prior when the model has
    one)."""
    with torch.no_grad():
        fast = m._build_fast()
        x0 = m._inputs(vel0, angvel0, fast)
        x_obs = x0.new_zeros(x0.shape[0], 0, 6) if obs_vel is None else m._inputs(obs_vel, obs_angvel, fast)[:, :steps]
        w_x = fast["w_x"]
        const0 = torch.addmm(fast["bias"][0], feature, w_x[0][6:])
        # the differentiable kernel, with the sliding prior of models that have one (the shipped model does)
        prior = torch.stack(m._prior_decel(feature), -1) if m.cfg.prior != "none" else x0.new_zeros(0, 3)
        return kernels.lstm_rollout(x0, x_obs, const0, [w_x[0][:6]] + w_x[1:], fast["w_h"], fast["bias"],
                                          fast["w_out"], fast["b_out"], fast["w_skip"], fast["gain"], int(steps),
                                          prior, fast["in"], fast["out"])


def previous_numpy_rollout(x0, x_obs, w0, w, w_head, steps, prior=None):
    """numpy_lstm_rollout written plainly (8 numpy calls per layer and step, out= keywords): the reference for the
    batch-1 kernel, which must give the same numbers bit for bit."""
    from physdyn_ros.learn.prior import prior_into

    layers = len(w) + 1
    hidden = w0.shape[1] // 4
    z = np.zeros(7 + layers * (hidden + 1) - 1, np.float32)
    z[:6] = x0
    views = []
    for layer in range(layers):
        lo = 7 + layer * (hidden + 1)
        z[lo - 1] = 1.0
        inp = z[:lo + hidden] if layer == 0 else z[lo - hidden - 1:lo + hidden]
        q = np.zeros(5 * hidden, np.float32)  # tanh of the gates (o, i, f, g) then the cell state c
        # per layer: product input, weights, tanh(gates) view, (o, i, f) view, (i, f), (g, c), c, o, h slot
        views.append((inp, w0 if layer == 0 else w[layer - 1], q[:4 * hidden], q[:3 * hidden],
                      q[hidden:3 * hidden], q[3 * hidden:], q[4 * hidden:], q[:hidden], z[lo:lo + hidden]))
    out = np.empty((steps, 13 + 6), np.float32)
    rows = list(out)
    x = z[:6]
    gates = np.empty(4 * hidden, np.float32)
    prod = np.empty(2 * hidden, np.float32)
    p_ig, p_fc = prod[:hidden], prod[hidden:]
    tc = np.empty(hidden, np.float32)
    one, half = np.float32(1.0), np.float32(0.5)
    dot, tanh, add, mul, copyto = np.dot, np.tanh, np.add, np.multiply, np.copyto
    observed = len(x_obs)
    for t in range(steps):
        for inp, weights, t4, u3, u_if, g_c, c, u_o, h in views:
            dot(inp, weights, out=gates)
            tanh(gates, out=t4)
            add(u3, one, out=u3)  # 2 sigmoid(a) for o, i, f
            mul(u_if, g_c, out=prod)  # (2 i tanh(g), 2 f c)
            add(p_ig, p_fc, out=c)
            mul(c, half, out=c)  # c <- f c + i tanh(g)
            tanh(c, out=tc)
            mul(u_o, tc, out=h)  # 2 o tanh(c)
        row = rows[t]
        dot(z, w_head, out=row)
        if prior is not None:  # the sliding prior: on the outputs and, through the gain, on the next input
            prior_into(row, x, prior)
        if t < observed:
            row[13:] = x_obs[t]
        copyto(x, row[13:])
    xs = np.empty((steps + 1, 6), np.float32)
    xs[0] = x0
    xs[1:] = out[:, 13:]
    return out[:, :13], xs


def close(new: torch.Tensor, ref: torch.Tensor, rel: float = REL) -> bool:
    err = (new - ref).abs().max().item()
    return err <= rel * max(ref.abs().max().item(), 1.0)


@pytest.fixture(scope="module")
def shipped():
    from physdyn_ros.predictor import Predictor

    return Predictor.load()


@pytest.fixture(scope="module")
def pushes(shipped):
    """Shape features and start velocities in frame C: the regression set's 20 test-split objects with their true
    initial velocities, then random pushes of the same shapes (0.1-1.5 m/s, up to 6 rad/s spin)."""
    from physdyn_ros.learn.frames import world_to_c

    d = dict(np.load(FIXTURE))
    codes = [shipped.encode(c) for c in d["cloud"]]
    rng = np.random.default_rng(7)
    n = 300
    idx = np.arange(n) % len(codes)
    v = d["lin_vel"][:, 0][idx]
    w = d["ang_vel"][:, 0][idx]
    speed, az = rng.uniform(0.1, 1.5, n), rng.uniform(-np.pi, np.pi, n)
    rand = np.arange(n) >= len(codes)
    v[rand] = np.stack([speed * np.cos(az), speed * np.sin(az), np.zeros(n)], 1)[rand]
    w[rand] = rng.normal(size=(n, 3))[rand] * [0.5, 0.5, 3.0]
    heading = np.array([codes[i].heading for i in idx])
    f32 = lambda a: torch.from_numpy(np.asarray(a, np.float32))  # noqa: E731
    # the dynamics network's part of the shape code (a model with a whole-push topple head appends descriptors)
    feature = f32(np.stack([codes[i].feature[:shipped._model.feature_dim] for i in idx]))
    obs_v = f32(world_to_c(d["lin_vel"][idx, 1:5], heading[:, None]))
    obs_w = f32(world_to_c(d["ang_vel"][idx, 1:5], heading[:, None]))
    return feature, f32(world_to_c(v, heading)), f32(world_to_c(w, heading)), obs_v, obs_w


def test_kernels_are_compiled():
    assert isinstance(kernels.lstm_rollout, torch.jit.ScriptFunction)
    assert isinstance(kernels.fused_lstm_rollout, torch.jit.ScriptFunction)


@pytest.mark.parametrize("batch", [1, 3, 300])  # 1: the numpy kernel; 300: two blocks of KERNEL_ROWS
@pytest.mark.parametrize("observed", [False, True])
def test_shipped_model_inference_kernels_equal_the_previous_kernel(shipped, pushes, batch, observed):
    m = shipped._model
    feature, v, w, obs_v, obs_w = (t[:batch] for t in pushes)
    obs = (obs_v, obs_w) if observed else (None, None)
    ref_raw, ref_xs = old_rollout_raw(m, feature, v, w, 60, *obs)
    with torch.inference_mode():
        raw, xs = m.rollout_raw(feature, v, w, 60, *obs)
    assert raw.shape == ref_raw.shape == (batch, 60, 13) and xs.shape == ref_xs.shape == (batch, 61, 6)
    assert close(raw, ref_raw) and close(xs, ref_xs)
    if observed:
        assert torch.equal(xs[:, 1:5], ref_xs[:, 1:5])  # observed inputs are copied, not computed
    # one step at a time the new kernel is the teacher-forced network on its own inputs
    scale = m._scale_vectors()["in"]
    with torch.no_grad():
        phys = xs[:, :-1] * scale
        teacher = m.teacher_forced(feature, phys[..., :3], phys[..., 3:])
    assert close(raw, teacher, 1e-5)
    # the numpy entry point of the Predictor gives the same numbers
    arr_raw, arr_xs, scales = m.rollout_arrays(feature.numpy(), v.numpy(), w.numpy(), 60,
                                               *(None if o is None else o.numpy() for o in obs))
    assert np.array_equal(arr_raw, raw.numpy()) and np.array_equal(arr_xs, xs.numpy())
    assert np.array_equal(scales["out"], m._scale_vectors()["out"].numpy())


@pytest.mark.parametrize("layers", [1, 2, 3])
@pytest.mark.parametrize("skip", [False, True])
@pytest.mark.parametrize("batch", [1, 5])
def test_any_architecture_equals_the_previous_kernel(layers, skip, batch):
    torch.manual_seed(layers)
    cfg = ModelConfig(num_points=64, pointnet=(32, 64), shape_mlp=(32, 8), hidden_size=32, num_layers=layers,
                      input_skip=skip)
    m = DynamicsModel(cfg, STATS).eval()
    if skip:
        torch.nn.init.normal_(m.skip.weight, std=0.05)
    feature, v, w = torch.randn(batch, 8), torch.randn(batch, 3) * 0.5, torch.randn(batch, 3) * 4
    ref_raw, ref_xs = old_rollout_raw(m, feature, v, w, 40)
    with torch.inference_mode():
        raw, xs = m.rollout_raw(feature, v, w, 40)
    assert close(raw, ref_raw) and close(xs, ref_xs)
    with torch.enable_grad():  # autograd on: still the differentiable kernel, the same numbers as before
        g_raw, _ = m.rollout_raw(feature, v, w, 40)
    assert g_raw.requires_grad and torch.equal(g_raw.detach(), ref_raw)


def test_kernel_weights_follow_parameter_updates():
    torch.manual_seed(0)
    m = DynamicsModel(ModelConfig(num_points=64, pointnet=(32, 64), shape_mlp=(32, 8), hidden_size=32), STATS).eval()
    feature, v, w = torch.randn(2, 8), torch.randn(2, 3), torch.randn(2, 3)
    with torch.inference_mode():
        before = m.rollout_raw(feature, v, w, 20)[0]
        one = m.rollout_raw(feature[:1], v[:1], w[:1], 20)[0]
    with torch.no_grad():
        m.lstm.weight_hh_l0.mul_(1.5)
        m.head.bias.add_(0.1)
    with torch.inference_mode():
        after = m.rollout_raw(feature, v, w, 20)[0]
        one_after = m.rollout_raw(feature[:1], v[:1], w[:1], 20)[0]
    assert not torch.allclose(before, after)
    assert close(after, old_rollout_raw(m, feature, v, w, 20)[0])
    assert close(one_after, old_rollout_raw(m, feature[:1], v[:1], w[:1], 20)[0]) and not torch.allclose(one, one_after)


# ------------------------------------------------------------------------------------------ the Predictor
def old_predictor_run(pred, feats, headings, v0, w0, p0, q0, horizon):
    """Predictor._run written plainly (without observed states): model.rollout in torch, then frames."""
    from physdyn_ros.learn.frames import c_to_world, integrate_in_world, world_to_c
    from physdyn_ros.learn.rules import consistent_topple, flat_unless_toppling, settle

    h = headings[:, None]
    dim = pred._model.feature_dim  # the dynamics network's part of the shape code
    with torch.inference_mode(False), torch.no_grad():
        fast = pred._model._build_fast()
        f32 = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float32))  # noqa: E731
        vel0, angvel0 = f32(world_to_c(v0, headings)), f32(world_to_c(w0, headings))
        raw, xs = old_rollout_raw(pred._model, f32(feats[:, :dim]), vel0, angvel0, horizon)
        out = pred._model.denormalize(raw, fast)
        x = xs * fast["in"]
        flat = torch.cat([out["d_pos"], out["d_rot"], x[:, 1:, :3], x[:, 1:, 3:], out["topple_logit"][..., None]],
                         -1).double().numpy()
    lin = np.concatenate([v0[:, None], c_to_world(flat[..., 6:9], h)], axis=1)
    ang = np.concatenate([w0[:, None], c_to_world(flat[..., 9:12], h)], axis=1)
    d_pos, d_rot = flat[..., 0:3].copy(), flat[..., 3:6].copy()
    prob = np.concatenate([np.zeros((len(feats), 1)), 1.0 / (1.0 + np.exp(-flat[..., 12]))], axis=1)
    d_rot_w, ang_c = c_to_world(d_rot, h), ang  # the rules are not part of the kernels: applied to both
    flat_unless_toppling(d_rot_w, ang_c, prob)
    topple = getattr(pred._model, "topple", None)
    if topple is not None:  # a whole-push topple head (not part of the speed-up either): applied as the Predictor does
        from physdyn_ros.learn.rules import topple_with_head

        head, _ = topple.assess(feats[:, :dim], feats[:, dim:], vel0.double().numpy(), angvel0.double().numpy())
        prob = topple_with_head(prob, head, d_rot_w, ang_c, 0, lambda rows, d: integrate_in_world(
            headings[rows], p0[rows], q0[rows], np.zeros_like(d), world_to_c(d, h[rows]))[1])
    settle(d_pos, d_rot_w, lin, ang_c)
    positions, orientations = integrate_in_world(headings, p0, q0, d_pos, world_to_c(d_rot_w, h))
    return positions, orientations, lin, ang, consistent_topple(prob, orientations)


def test_predictor_equals_the_previous_predictor(shipped):
    d = dict(np.load(FIXTURE))
    rng = np.random.default_rng(11)
    code = shipped.encode(d["cloud"][3])
    v, w = rng.normal(size=(6, 3)) * [0.7, 0.7, 0.0], rng.normal(size=(6, 3)) * [0.5, 0.5, 3.0]
    q0 = geo.quat_normalize(rng.normal(size=(6, 4)))
    p0 = rng.normal(size=(6, 3))
    batch = shipped.rollout_batch(code, v, w, 60, positions=p0, orientations=q0)
    singles = [shipped.rollout(code, v[i], w[i], 60, position=p0[i], orientation=q0[i]) for i in range(6)]
    ref = old_predictor_run(shipped, np.repeat(code.feature[None], 6, 0), np.full(6, code.heading), v, w, p0, q0, 60)
    for name, r in zip(("positions", "orientations", "lin_vels", "ang_vels", "topple_prob"), ref):
        for got in (getattr(batch, name), np.stack([getattr(t, name) for t in singles])):
            if name == "orientations":
                assert geo.quat_angle_between(got, r).max() < 1e-5 and np.all(got[..., 3] >= 0)
            else:
                assert np.abs(got - r).max() <= REL * max(np.abs(r).max(), 1.0), name


@pytest.mark.parametrize("about_z", ["none", "some", "all"])  # rows turning about z only: the running-yaw branch
@pytest.mark.parametrize("batch", [4, 40])  # 4 x 62 quaternions: as 4x4 matrices; 40 x 62: by components
def test_compose_rotations_equals_integrate_in_world(batch, about_z):
    from physdyn_ros.learn.frames import integrate_in_world
    from physdyn_ros.predictor import compose_rotations

    rng = np.random.default_rng(5)
    d_rot = rng.normal(size=(batch, 61, 3)) * rng.choice([0.01, 0.3, 1.5, 3.0], batch)[:, None, None]
    d_rot[0, :5] = 0.0  # exact identities
    d_rot[{"none": [], "some": [1, 2], "all": slice(None)}[about_z], :, :2] = 0.0
    q0 = geo.quat_normalize(rng.normal(size=(batch, 4)))
    _, ref = integrate_in_world(np.zeros(batch), np.zeros((batch, 3)), q0, np.zeros_like(d_rot), d_rot)
    got = compose_rotations(q0, d_rot)
    assert got.shape == (batch, 62, 4) and np.allclose(np.linalg.norm(got, axis=-1), 1.0)
    assert np.abs(got - ref).max() < 1e-12  # both have w >= 0


@pytest.mark.parametrize("observed", [False, True])
def test_batch1_numpy_kernel_equals_its_previous_version_bit_for_bit(shipped, pushes, observed):
    """The batch-1 kernel (7 numpy calls per layer, the sliding prior's constants in numpy) gives the same float32
    numbers as the plain version, for every push of the fixture."""
    from physdyn_ros.learn.prior import prior_constants

    m = shipped._model
    feature, v, w, obs_v, obs_w = pushes
    with torch.inference_mode():
        kernel = m._kernel(m._fast())
        prior = torch.stack(m._prior_decel(feature), -1).numpy()
    scale_in = kernel["np_in"]
    for i in range(0, 300, 7):
        x0 = (torch.cat([v[i], w[i]]).numpy() / scale_in).astype(np.float32)
        x_obs = (torch.cat([obs_v[i], obs_w[i]], -1).numpy() / scale_in).astype(np.float32) if observed \
            else np.zeros((0, 6), np.float32)
        w0 = kernel["np_w0"].copy()
        w0[6] = feature[i].numpy() @ kernel["np_w_feature"] + kernel["np_b0"]
        args = prior_constants(prior[i, 0], prior[i, 1], kernel["np_in"], kernel["np_out"], kernel["np_gain"],
                               coupling=float(prior[i, 2]))  # the shipped model's coupled prior
        ref = previous_numpy_rollout(x0, x_obs, w0, kernel["np_w"], kernel["np_head"], 60, args)
        got = kernels.numpy_lstm_rollout(x0, x_obs, w0, kernel["np_w"], kernel["np_head"], 60, args)
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1]), i
        # the Predictor's entry point: the prior's constants now computed in numpy, the same numbers
        arr_raw, arr_xs, _ = m.rollout_arrays(feature[i:i + 1].numpy(), v[i:i + 1].numpy(), w[i:i + 1].numpy(), 60,
                                              *((obs_v[i:i + 1].numpy(), obs_w[i:i + 1].numpy()) if observed
                                                else (None, None)))
        with torch.inference_mode():
            ref_raw, ref_xs = m.rollout_raw(feature[i:i + 1], v[i:i + 1], w[i:i + 1], 60,
                                            *((obs_v[i:i + 1], obs_w[i:i + 1]) if observed else (None, None)))
        assert np.array_equal(arr_raw, ref_raw.numpy()) and np.array_equal(arr_xs, ref_xs.numpy()), i
