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
"""Roll-out precision (learn/kernels.py): bf16 products where the CPU has bf16 arithmetic, float32 elsewhere.

* "auto" follows the flags the CPU reports (the flag reader monkeypatched: both kinds of CPU are tested on any
  machine) and the batch size; "fp32" and "bf16" force one; anything else is refused.
* float32 stays bit for bit what it was, whatever the CPU: "fp32", and "auto" on a CPU without bf16 arithmetic,
  equal the float32 kernel exactly.
* bf16 forced on (it runs on any CPU; without bf16 arithmetic torch emulates it) stays within the model card's
  bounds of float32 with the shipped model: final position median changed by at most 0.1 cm and p90 by at most
  0.3 cm, whole-push topple decisions identical on at least 99.5 % of the pushes. The held-out-split figures are
  bench/precision.py's.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdyn_ros.learn import cell_bf16, kernels
from physdyn_ros.learn import precision as prec

FIXTURE = Path(__file__).parent / "fixtures" / "regression_set.npz"
AVX2_ONLY = frozenset({"fpu", "sse4_2", "avx", "avx2", "fma"})  # e.g. AMD Zen 3
SAPPHIRE_RAPIDS = AVX2_ONLY | {"avx512f", "avx512_bf16", "amx_tile", "amx_bf16"}
AVX512_BF16_ONLY = AVX2_ONLY | {"avx512f", "avx512_bf16"}  # e.g. AMD Zen 4, Intel Cooper Lake
#: the model card's bounds
MAX_MEDIAN_CM, MAX_P90_CM, MIN_AGREEMENT = 0.1, 0.3, 0.995


def flags(monkeypatch: pytest.MonkeyPatch, reported: frozenset) -> None:
    monkeypatch.setattr(prec, "cpu_flags", lambda: reported)


@pytest.fixture(scope="module")
def predictors():
    """The shipped model with fp32, bf16 and auto precision (one model shared: the same weights)."""
    from physdyn_ros.predictor import Predictor

    fp32 = Predictor.load(precision="fp32")
    return {p: fp32 if p == "fp32" else Predictor(fp32._model, {"model_id": fp32.model_id}, precision=p)
            for p in ("fp32", "bf16", "auto")}


@pytest.fixture(scope="module")
def pushes(predictors):
    """256 pushes of the regression set's 20 test-split objects: their true initial states, then random pushes
    (0.1-1.5 m/s, spin up to ~9 rad/s), the planner's kind of batch."""
    pred = predictors["fp32"]
    d = dict(np.load(FIXTURE))
    codes = pred.encode_many(list(d["cloud"].astype(np.float64)))
    n = 256
    rng = np.random.default_rng(5)
    idx = np.arange(n) % len(codes)
    v, w = d["lin_vel"][idx, 0].copy(), d["ang_vel"][idx, 0].copy()
    rand = np.arange(n) >= len(codes)
    speed, az = rng.uniform(0.1, 1.5, n), rng.uniform(-np.pi, np.pi, n)
    v[rand] = np.stack([speed * np.cos(az), speed * np.sin(az), np.zeros(n)], 1)[rand]
    w[rand] = (rng.normal(size=(n, 3)) * [0.5, 0.5, 3.0])[rand]
    return [codes[i] for i in idx], v, w, d, idx


@pytest.fixture(autouse=True)
def no_isa_cap(monkeypatch):
    """No oneDNN instruction-set cap from the environment the tests run in (the tests that want one set it)."""
    for name in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        monkeypatch.delenv(name, raising=False)


def test_auto_follows_the_cpu_flags_and_the_batch(monkeypatch):
    flags(monkeypatch, AVX2_ONLY)
    assert not prec.cpu_has_bf16()
    assert prec.resolve_precision("auto") == "fp32"
    assert prec.resolve_precision("auto", "cpu", 4096) == "fp32"
    assert prec.resolve_precision("bf16", "cpu", 8) == "bf16"  # forced: runs (emulated) on any CPU
    for reported in (SAPPHIRE_RAPIDS, AVX512_BF16_ONLY, AVX2_ONLY | {"amx_bf16"}):
        flags(monkeypatch, reported)
        assert prec.cpu_has_bf16()
        assert prec.resolve_precision("auto") == "bf16"
        assert prec.resolve_precision("auto", "cpu", prec.AUTO_BF16_ROWS) == "bf16"
        assert prec.resolve_precision("auto", "cpu", prec.AUTO_BF16_ROWS - 1) == "fp32"  # no faster there
        assert prec.resolve_precision("fp32", "cpu", 4096) == "fp32"
        assert prec.resolve_precision("auto", "cuda:0") == "fp32"  # the bf16 kernel is the CPU's


def test_auto_keeps_fp32_where_onednn_is_capped_below_bf16(monkeypatch):
    flags(monkeypatch, SAPPHIRE_RAPIDS)
    for name, cap in (("ONEDNN_MAX_CPU_ISA", "AVX2"), ("ONEDNN_MAX_CPU_ISA", "avx512_core_vnni"),
                      ("DNNL_MAX_CPU_ISA", "AVX512_CORE")):
        monkeypatch.setenv(name, cap)
        assert not prec.cpu_has_bf16(), cap  # oneDNN would emulate the bf16 products: 100x slower
        assert prec.resolve_precision("auto", "cpu", 4096) == "fp32"
        assert prec.resolve_precision("bf16", "cpu", 4096) == "bf16"  # forced: runs
        monkeypatch.delenv(name)
    for cap in ("AVX512_CORE_BF16", "AVX512_CORE_AMX", "ALL", ""):
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", cap)
        assert prec.cpu_has_bf16(), cap
        assert prec.resolve_precision("auto", "cpu", 4096) == "bf16"


def test_unknown_precisions_and_bf16_off_the_cpu_are_refused(monkeypatch):
    from physdyn_ros.predictor import Predictor

    for bad in ("fp16", "float32", "", "BF16"):
        with pytest.raises(ValueError, match="precision must be one of auto, fp32, bf16"):
            prec.resolve_precision(bad)
        with pytest.raises(ValueError, match="precision must be one of"):
            Predictor.load(precision=bad)
    with pytest.raises(ValueError, match="bf16 runs on the CPU only"):
        prec.resolve_precision("bf16", "cuda")


def test_the_flag_reader_reads_this_cpu():
    reported = prec.cpu_flags()
    assert isinstance(reported, frozenset)
    if Path("/proc/cpuinfo").is_file():
        text = Path("/proc/cpuinfo").read_text(errors="replace")
        line = next(x for x in text.splitlines() if x.startswith("flags"))
        assert reported == frozenset(line.split(":", 1)[1].split())
        assert prec.cpu_has_bf16() == any(f" {flag} " in f" {line} " for flag in ("avx512_bf16", "amx_bf16"))


def test_bf16_kernel_is_compiled():
    assert isinstance(kernels.bf16_lstm_rollout, torch.jit.ScriptFunction)


def test_fp32_is_bit_identical_whatever_the_cpu(monkeypatch, predictors, pushes):
    """fp32, and auto on an AVX2-only CPU, are the float32 kernel bit for bit (at a batch auto would run in bf16
    on a bf16 CPU); the float32 kernel's weights and results are untouched by the bf16 ones beside them."""
    codes, v, w, _, _ = pushes
    ref = predictors["fp32"].rollout_batch(codes, v, w, 60)
    m = predictors["fp32"]._model
    feats = np.stack([c.feature[:m.feature_dim] for c in codes]).astype(np.float32)
    with torch.inference_mode():
        fast = m._fast()
        kernel = m._kernel(fast)
        f = torch.from_numpy(feats)
        vel, ang = torch.from_numpy(v.astype(np.float32)), torch.from_numpy(w.astype(np.float32))
        raw, xs = m.rollout_raw(f, vel, ang, 60, precision="fp32")
        x0 = m._inputs(vel, ang, fast)
        prior = torch.stack(m._prior_decel(f), -1)
        direct = kernels.fused_rollout({k: kernel[k] for k in ("w", "b", "w_feature", "head", "b_head", "gain")},
                                       f, x0, x0.new_zeros(len(x0), 0, 6), 60, prior, fast["in"], fast["out"])
    assert torch.equal(raw, direct[0]) and torch.equal(xs, direct[1])
    for reported in (AVX2_ONLY, SAPPHIRE_RAPIDS):
        flags(monkeypatch, reported)
        for precision in ("fp32", "auto") if reported is AVX2_ONLY else ("fp32",):
            pred = predictors[precision]
            assert pred.batch_precision(len(codes)) == "fp32"
            got = pred.rollout_batch(codes, v, w, 60)
            for name in ("positions", "orientations", "lin_vels", "ang_vels", "topple_prob"):
                assert np.array_equal(getattr(got, name), getattr(ref, name)), (precision, name)


def test_auto_on_a_bf16_cpu_runs_large_batches_in_bf16(monkeypatch, predictors, pushes):
    """The planner's batches (128 candidates) and larger run in bf16 under auto; smaller ones keep float32."""
    codes, v, w, _, _ = pushes
    flags(monkeypatch, SAPPHIRE_RAPIDS)
    auto, bf16, fp32 = predictors["auto"], predictors["bf16"], predictors["fp32"]
    n = prec.AUTO_BF16_ROWS
    assert auto.batch_precision(n) == bf16.batch_precision(n) == "bf16" and auto.batch_precision(1) == "fp32"
    big = auto.rollout_batch(codes[:n], v[:n], w[:n], 30)
    assert np.array_equal(big.positions, bf16.rollout_batch(codes[:n], v[:n], w[:n], 30).positions)
    assert not np.array_equal(big.positions, fp32.rollout_batch(codes[:n], v[:n], w[:n], 30).positions)
    small = auto.rollout_batch(codes[:n - 1], v[:n - 1], w[:n - 1], 30)
    assert np.array_equal(small.positions, fp32.rollout_batch(codes[:n - 1], v[:n - 1], w[:n - 1], 30).positions)
    # batch 1 is the float32 numpy kernel in every precision
    one = bf16.rollout(codes[0], v[0], w[0], 30)
    assert np.array_equal(one.positions, fp32.rollout(codes[0], v[0], w[0], 30).positions)


def test_bf16_stays_within_the_stated_bounds_of_fp32(predictors, pushes):
    """The shipped model, 256 pushes: final positions moved by bf16, the error against the simulation of the
    regression set's true pushes, and whole-push topple decisions."""
    codes, v, w, d, idx = pushes
    p0 = d["pos"][idx, 0]
    q0 = d["quat"][idx, 0]
    a = predictors["fp32"].rollout_batch(codes, v, w, 60, positions=p0, orientations=q0)
    b = predictors["bf16"].rollout_batch(codes, v, w, 60, positions=p0, orientations=q0)
    assert not np.array_equal(a.positions, b.positions)  # bf16 did run
    moved = np.linalg.norm(b.positions[:, -1] - a.positions[:, -1], axis=-1) * 100.0
    assert np.median(moved) <= MAX_MEDIAN_CM and np.percentile(moved, 90) <= MAX_P90_CM, moved
    agree = np.mean((a.topple_probability > 0.5) == (b.topple_probability > 0.5))
    assert agree >= MIN_AGREEMENT, agree
    # against the simulation: the regression set's 20 true pushes (frame 60 of 61 recorded frames)
    true = np.arange(len(idx)) < len(d["pos"])
    calm = true & ~d["toppled"][idx].astype(bool)
    err = {k: np.linalg.norm(t.positions[calm, -1] - d["pos"][idx[calm], 60], axis=-1) * 100.0
           for k, t in (("fp32", a), ("bf16", b))}
    assert abs(np.median(err["bf16"]) - np.median(err["fp32"])) <= MAX_MEDIAN_CM
    assert abs(np.percentile(err["bf16"], 90) - np.percentile(err["fp32"], 90)) <= MAX_P90_CM


def test_bf16_kernel_branches(monkeypatch):
    """A model without prior or input skip, observed steps, several kernel blocks: the bf16 kernel computes the
    float32 kernel's function (within bf16 rounding) in every branch, block boundaries included."""
    from physdyn_ros.learn.model import STAT_KEYS, DynamicsModel, ModelConfig

    cfg = ModelConfig.from_dict({"num_points": 64, "pointnet": [16, 32], "shape_mlp": [16, 8], "cell": "lstm",
                                 "hidden_size": 16, "num_layers": 3, "max_horizon": 80})
    torch.manual_seed(3)
    model = DynamicsModel(cfg, dict(zip(STAT_KEYS, (0.5, 8.0, 0.2, 4.0, 0.03, 0.5, 0.15)))).eval()
    monkeypatch.setattr(kernels, "BF16_ROWS", 16)  # 40 rows: three blocks
    gen = torch.Generator().manual_seed(4)
    feature = torch.randn(40, model.feature_dim, generator=gen)
    vel, ang = torch.randn(40, 3, generator=gen) * 0.5, torch.randn(40, 3, generator=gen)
    obs_v, obs_w = vel[:, None].repeat(1, 3, 1) * 0.9, ang[:, None].repeat(1, 3, 1) * 0.8
    with torch.inference_mode():
        for obs in ((None, None), (obs_v, obs_w)):
            ref_raw, ref_xs = model.rollout_raw(feature, vel, ang, 25, *obs, precision="fp32")
            raw, xs = model.rollout_raw(feature, vel, ang, 25, *obs, precision="bf16")
            assert raw.dtype == xs.dtype == torch.float32 and raw.shape == ref_raw.shape
            assert not torch.equal(raw, ref_raw)
            scale = max(ref_raw.abs().max().item(), 1.0)
            assert (raw - ref_raw).abs().max().item() <= 0.02 * scale
            assert (xs - ref_xs).abs().max().item() <= 0.02 * max(ref_xs.abs().max().item(), 1.0)
            if obs[0] is not None:
                assert torch.equal(xs[:, 1:4], ref_xs[:, 1:4])  # observed inputs are copied, not computed
            # each block on its own gives the same rows: the blocks are independent
            part = model.rollout_raw(feature[16:32], vel[16:32], ang[16:32], 25,
                                     *(None if o is None else o[16:32] for o in obs), precision="bf16")
            assert torch.equal(part[0], raw[16:32])


needs_c_cell = pytest.mark.skipif(not cell_bf16.available(cell_bf16.WIDTH),
                                  reason=f"the bf16 kernel's C cell does not run here: {cell_bf16.status()}")


def _torch_cell(g: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """bf16_lstm_rollout's cell step in torch: gates (rows, 4 H) bf16, c' (rows, H) float32 -> new c', h (bf16)."""
    hidden = c.shape[1]
    s = g.float().sigmoid()
    s_i, s_f, s_o, s_g = (s[:, k * hidden:(k + 1) * hidden] for k in range(4))
    c = c.clone().mul_(s_f).addcmul_(s_i, s_g, value=-4.0).add_(s_i, alpha=2.0)
    return c, torch.addcmul(s_o, s_o, torch.sigmoid(c), value=-2.0).to(torch.bfloat16)


@needs_c_cell
def test_c_cell_step_is_torchs_up_to_float32_rounding():
    """One cell step in C against the TorchScript kernel's arithmetic: the cell state within float32 rounding, the
    bf16 hidden state identical but where a last-bit difference flips its rounding (one bf16 step), rows read and
    written through strides (h is a view into the kernel's row buffer)."""
    gen = torch.Generator().manual_seed(7)
    rows, hidden = 37, 48
    g = (torch.randn(rows, 4 * hidden, generator=gen) * 4.0).to(torch.bfloat16)
    g[0, :4] = torch.tensor([90.0, -90.0, 0.0, 1e-3])  # saturated gates
    g[1, 0], g[1, hidden + 1] = float("nan"), float("inf")  # a NaN stays NaN, as in torch
    c0 = torch.randn(rows, hidden, generator=gen) * 3.0
    ref_c, ref_h = _torch_cell(g, c0)
    c = c0.clone()
    z = torch.full((rows, hidden + 20), 7.0, dtype=torch.bfloat16)
    h = z[:, 10:10 + hidden]
    (cell, _), _ = cell_bf16._cell()
    assert cell(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), h.data_ptr(), z.stride(0), rows, hidden) == 0
    assert ref_c[1, 0].isnan() and torch.equal(c.isnan(), ref_c.isnan()) and torch.equal(h.isnan(), ref_h.isnan())
    assert torch.allclose(c, ref_c, rtol=1e-6, atol=1e-6, equal_nan=True), (c - ref_c).abs().nan_to_num().max()
    step = ((h.float() - ref_h.float()).abs() / ref_h.float().abs().clamp_min(2.0 ** -120)).nan_to_num()
    assert step.max() <= 2.0 ** -7 and (h != ref_h).float().mean() < 0.01
    assert torch.all(z[:, :10] == 7.0) and torch.all(z[:, 10 + hidden:] == 7.0)  # nothing outside h written
    assert cell(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), h.data_ptr(), z.stride(0), rows, 40) == -1


@needs_c_cell
def test_c_prior_is_prior_raw():
    """The sliding prior in C (the step tail's, with a head of zeros: its outputs are the prior alone) against
    prior_raw through the kernel's strides: sliding, spinning, both (coupled and not), at rest, stopping within the
    step and NaN / inf inputs: equal up to float32 rounding, NaN where prior_raw gives NaN; the topple column and
    the other steps untouched."""
    from physdyn_ros.conventions import DT
    from physdyn_ros.learn.prior import prior_raw

    gen = torch.Generator().manual_seed(9)
    rows, hidden = 64, 16
    x = torch.randn(rows, 6, generator=gen)
    x[:8] = 0.0  # at rest
    x[8:16, 5] = 0.0  # sliding only
    x[16:24, :2] = 0.0  # spinning only
    x[24:32] *= 1e-3  # stops within the step
    x[32, 0], x[33, 5], x[34, 1] = float("nan"), float("nan"), float("inf")  # propagated as torch's clamps do
    prior = torch.stack([torch.rand(rows, generator=gen) * 5.0, torch.rand(rows, generator=gen) * 50.0,
                         (torch.arange(rows) % 2).float()], 1)
    scale_in, scale_out = torch.rand(6, generator=gen) + 0.5, torch.rand(13, generator=gen) + 0.5
    want = prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out)
    y, xs = torch.full((rows, 3, 13), 5.0), torch.zeros(rows, 2, 6)
    zeros, gain = torch.zeros(hidden // 2, 16, 2, dtype=torch.bfloat16), torch.zeros(6)
    b16, z = torch.zeros(16), torch.zeros(rows, 6 + hidden, dtype=torch.bfloat16)
    g, c = torch.zeros(rows, 4 * hidden, dtype=torch.bfloat16), torch.zeros(rows, hidden)
    tail = cell_bf16.Tail(w_pairs=zeros.data_ptr(), b_head=b16.data_ptr(), prior=prior.data_ptr(), p_stride=3,
                          scale_in=scale_in.data_ptr(), scale_out=scale_out.data_ptr(), dt=DT, gain=gain.data_ptr(),
                          x=x.data_ptr(), x_stride=6, y=y[:, 1].data_ptr(), y_stride=y.stride(0),
                          xs=xs[:, 1].data_ptr(), xs_stride=xs.stride(0), zx=z.data_ptr(), z_stride=z.stride(0))
    (_, last), _ = cell_bf16._cell()
    assert last(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), z[:, 6:].data_ptr(), z.stride(0), rows, hidden,
                tail) == 0
    # within float32 rounding of each row's operands (torch's sqrt may differ by one ulp from C's correctly rounded
    # one), NaN where prior_raw gives NaN
    size = (x * scale_in).abs().nan_to_num(posinf=0.0).amax(1, keepdim=True) / scale_out[:12].min()
    got = y[:, 1, :12]
    assert torch.all(((got - want).abs() <= 1e-6 * (1.0 + size)) | (got.isnan() & want.isnan())), (got - want).abs()
    assert got[32:35].isnan().any() and torch.equal(got.isnan(), want.isnan())
    assert torch.all(y[:, 1, 12] == 0.0) and torch.all(y[:, [0, 2]] == 5.0)
    assert torch.all(got[:8] == 0.0) and (got[8:] != 0.0).any(1).all()  # rows at rest: prior 0


def _tail_case(rows: int, hidden: int, observed: bool, with_prior: bool, gen: torch.Generator) -> dict:
    """Operands of one step tail (c_bf16_lstm_rollout's layout) and what torch computes from them."""
    from physdyn_ros.conventions import DT
    from physdyn_ros.learn.prior import prior_raw

    z = torch.full((rows, 10 + hidden + 4), 7.0, dtype=torch.bfloat16)  # [x (6), 4 others, h, 4 others]
    h = z[:, 10:10 + hidden]
    x = torch.randn(rows, 6, generator=gen)
    x[:4] = 0.0  # at rest: the prior adds nothing
    z[:, :6] = x
    w_out = torch.randn(hidden, 13, generator=gen).to(torch.bfloat16)
    w_skip, b_head, gain = torch.randn(6, 13, generator=gen), torch.randn(13, generator=gen), torch.rand(6) + 0.5
    x_obs = torch.randn(rows, 2, 6, generator=gen)
    prior = torch.stack([torch.rand(rows, generator=gen) * 5.0, torch.rand(rows, generator=gen) * 50.0,
                         (torch.arange(rows) % 2).float()], 1)
    scale_in, scale_out = torch.rand(6, generator=gen) + 0.5, torch.rand(13, generator=gen) + 0.5
    g = (torch.randn(rows, 4 * hidden, generator=gen) * 3.0).to(torch.bfloat16)
    c = torch.randn(rows, hidden, generator=gen)
    ref_c, ref_h = _torch_cell(g, c)
    y = b_head + x @ w_skip + ref_h.float() @ w_out.float()  # the head's products in float32, not rounded
    head = y.clone()
    if with_prior:
        y[:, :12] += prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out)
    nxt = x_obs[:, 1] if observed else x + y[:, :6] * gain
    w_pairs = torch.zeros(hidden // 2, 16, 2, dtype=torch.bfloat16)
    w_pairs[:, :13] = w_out.reshape(hidden // 2, 2, 13).transpose(1, 2)
    skip16, b16 = torch.zeros(6, 16), torch.zeros(16)
    skip16[:, :13], b16[:13] = w_skip, b_head
    ys, xs = torch.full((rows, 3, 13), 5.0), torch.full((rows, 4, 6), 5.0)
    tail = cell_bf16.Tail(w_pairs=w_pairs.data_ptr(), w_skip=skip16.data_ptr(), b_head=b16.data_ptr(), dt=DT,
                          x_obs=x_obs[:, 1].data_ptr() if observed else None, obs_stride=x_obs.stride(0),
                          gain=gain.data_ptr(), x=x.data_ptr(), x_stride=6, y=ys[:, 1].data_ptr(),
                          y_stride=ys.stride(0), xs=xs[:, 2].data_ptr(), xs_stride=xs.stride(0), zx=z.data_ptr(),
                          z_stride=z.stride(0))
    if with_prior:
        tail.prior, tail.p_stride = prior.data_ptr(), 3
        tail.scale_in, tail.scale_out = scale_in.data_ptr(), scale_out.data_ptr()
    return dict(z=z, h=h, x=x, g=g, c=c, ys=ys, xs=xs, tail=tail, keep=(w_pairs, skip16, b16, x_obs, prior, scale_in,
                scale_out, gain), ref_c=ref_c, ref_h=ref_h, y=y, head=head, next=nxt)


@needs_c_cell
@pytest.mark.parametrize("observed,with_prior", [(False, True), (True, True), (False, False)])
def test_c_step_tail_is_the_torch_step(observed, with_prior):
    """The last layer's cell with the step tail in C against torch: the cell as the cell alone; the head's output
    within float32 rounding of b_head + x w_skip + h w_out (its products in float32), plus the prior where there
    is one; the next input (observed, or integrated) stored in x, in the record and, rounded to bf16, in the row
    buffer; nothing else written."""
    gen = torch.Generator().manual_seed(11)
    rows, hidden = 37, 48
    case = _tail_case(rows, hidden, observed, with_prior, gen)
    (_, last), _ = cell_bf16._cell()
    g, c, z = case["g"], case["c"], case["z"]
    assert last(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), case["h"].data_ptr(), z.stride(0), rows, hidden,
                case["tail"]) == 0
    assert torch.allclose(c, case["ref_c"], rtol=1e-6, atol=1e-6)
    # h equal but where a last-bit difference of the sigmoids flips its bf16 rounding; the head then reads that h
    flipped = (case["h"] != case["ref_h"]).any(1)
    assert flipped.float().mean() < 0.3
    ys, xs, want = case["ys"], case["xs"], case["y"]
    size = 1.0 + want.abs()
    assert torch.all((ys[~flipped, 1] - want[~flipped]).abs() <= 1e-5 * size[~flipped]), (ys[:, 1] - want).abs().max()
    assert torch.all((ys[:, 1] - want).abs() <= 0.05 * size)
    nxt = case["next"]
    close = (case["x"] - nxt).abs() <= 1e-5 * (1.0 + nxt.abs())
    assert torch.all(close[~flipped]) and torch.equal(case["x"], xs[:, 2])
    assert torch.equal(z[:, :6], case["x"].to(torch.bfloat16))  # rounded to nearest even, as torch rounds
    assert torch.all(ys[:, [0, 2]] == 5.0) and torch.all(xs[:, [0, 1, 3]] == 5.0)  # other steps untouched
    assert torch.all(z[:, 6:10] == 7.0) and torch.all(z[:, 10 + hidden:] == 7.0)
    if with_prior:  # the prior moved every moving row's outputs, and none of those at rest
        moved = ((want - case["head"]).abs() > 1e-3).any(1)
        assert not moved[:4].any() and moved[4:].all()
    assert last(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), case["h"].data_ptr(), z.stride(0), rows, 40,
                case["tail"]) == -1


@needs_c_cell
def test_c_step_tail_rounds_the_next_input_to_bf16_as_torch_does():
    """The next input's bf16 copy in the row buffer (what the next products read): round to nearest even on ties,
    overflow to inf, inf and NaN kept, as torch's conversion."""
    gen = torch.Generator().manual_seed(12)
    rows, hidden = 4, 16
    case = _tail_case(rows, hidden, True, False, gen)
    special = torch.tensor([1 + 2 ** -8, 1 + 3 * 2 ** -8, -(1 + 2 ** -8), 3.4e38, float("inf"), float("nan"),
                            -float("inf"), 2 ** -130, -0.0, 1e-3, 65504.0, -3.0e38], dtype=torch.float32)
    obs = case["keep"][3]
    obs[:, 1] = special[:rows * 6].reshape(rows, 6) if special.numel() >= rows * 6 else torch.cat(
        [special, torch.randn(rows * 6 - special.numel(), generator=gen)]).reshape(rows, 6)
    (_, last), _ = cell_bf16._cell()
    g, c, z = case["g"], case["c"], case["z"]
    assert last(g.data_ptr(), g.stride(0), c.data_ptr(), c.stride(0), case["h"].data_ptr(), z.stride(0), rows, hidden,
                case["tail"]) == 0
    want = obs[:, 1].to(torch.bfloat16)
    got = z[:, :6]
    assert torch.equal(got.isnan(), want.isnan()) and torch.equal(got[~want.isnan()], want[~want.isnan()])
    assert got[0, 0] == 1.0 and got[0, 3] == float("inf")  # a tie to the even neighbour; overflow


@needs_c_cell
def test_c_cell_rollout_is_the_torchscript_bf16_kernel(predictors):
    """The shipped model's bf16 roll-out through the C cell against the TorchScript bf16 kernel, 64 pushes of 60
    steps: both ran, and the C one is no farther from float32 (its head's products are not rounded to bf16; the
    other differences are the sigmoids' last bits)."""
    model = predictors["fp32"]._model
    gen = torch.Generator().manual_seed(8)
    rows = 64
    feature = torch.randn(rows, model.feature_dim, generator=gen) * 0.5
    vel = torch.randn(rows, 3, generator=gen) * torch.tensor([0.6, 0.6, 0.0])
    ang = torch.randn(rows, 3, generator=gen) * torch.tensor([0.3, 0.3, 3.0])
    with torch.inference_mode():
        c_raw, c_xs = model.rollout_raw(feature, vel, ang, 60, precision="bf16")
        ref32, ref_xs = model.rollout_raw(feature, vel, ang, 60, precision="fp32")
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(cell_bf16, "available", lambda hidden: False)
            ts_raw, ts_xs = model.rollout_raw(feature, vel, ang, 60, precision="bf16")
    assert not torch.equal(c_raw, ts_raw)  # each kernel ran
    c_err, ts_err = (c_raw - ref32).abs().mean().item(), (ts_raw - ref32).abs().mean().item()
    assert c_err <= 1.05 * ts_err, (c_err, ts_err)
    # per push, the largest difference of the inputs over the roll-out (a few pushes diverge in any two kernels):
    # the typical push's C inputs stay nearer the TorchScript kernel's than either is to float32
    worst = lambda a, b: (a - b).abs().amax((1, 2)).median().item()  # noqa: E731
    assert worst(c_xs, ref_xs) <= 1.1 * worst(ts_xs, ref_xs)
    assert worst(c_xs, ts_xs) <= 0.75 * worst(ts_xs, ref_xs)


def test_c_cell_takes_only_whole_vectors_of_hidden_units():
    """Hidden sizes that are not a multiple of the cell's vector width run the TorchScript kernel."""
    assert not cell_bf16.available(cell_bf16.WIDTH + 8)
    with pytest.raises(RuntimeError, match="C cell cannot run"):
        w = [torch.zeros(7 + 24, 96, dtype=torch.bfloat16)]
        cell_bf16.c_bf16_lstm_rollout(torch.zeros(2, 6), torch.zeros(2, 0, 6), torch.zeros(2, 0), w,
                                      torch.zeros(24, 13, dtype=torch.bfloat16), torch.zeros(0, 13), torch.zeros(13),
                                      torch.zeros(6), 3, torch.zeros(0, 3), torch.ones(6), torch.ones(13))
