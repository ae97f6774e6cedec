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
"""The roll-out kernels: a network's closed loop over many steps, in implementations of one function.

    lstm_rollout        TorchScript, differentiable: training with feedback (autograd on)
    fused_lstm_rollout  TorchScript, no autograd: one product per layer and step, sigmoid only, buffers made once
    bf16_lstm_rollout   fused_lstm_rollout with bf16 matrix products (fp32 accumulation, fp32 state): batched
                        roll-outs on CPUs with bf16 arithmetic (precision "bf16", or "auto" where the CPU has it);
                        where the CPU has AVX-512 BF16, cell_bf16.c_bf16_lstm_rollout: its cell, head and prior in C
    numpy_lstm_rollout  numpy, batch 1 on the CPU: the Predictor's latency path (always float32)
    mlp_rollout         the paper's memoryless MLP baseline, eagerly (not latency critical)

Each step computes the raw outputs y (13: d_vel, d_angvel, d_pos, d_rot normalised, topple logit) from the
normalised input x = [v, w] / scale (6), the shape feature and the recurrent state, adds the sliding prior
(learn/prior.py) when the model has one, then feeds back x + gain * y[:6] (the model's own velocities) or, for the
first K steps, the observed input. The LSTM kernels read weights prepared once per parameter change
(lstm_weights, kernel_weights), which DynamicsModel caches. test_rollout_kernels holds the kernels to one function,
test_rollout_identity to the shipped model's numbers bit for bit (in float32), test_precision the bf16 kernel to
the float32 one within the accuracy the model card states.
"""
from __future__ import annotations

from typing import Any, List, Optional, Tuple

import numpy as np
import torch
from torch import Tensor, nn

from .prior import prior_constants, prior_into, prior_raw
from .native import c_lstm_rollout, packed_weights, use_c
from . import cell_bf16

#: Per-step outputs: d_vel (0:3), d_angvel (3:6), d_pos (6:9), d_rot (9:12), topple logit (12).
OUT_DIM = 13
#: Rows per call of the fused inference kernel on the CPU: a block's gate buffers (4 x rows x 4 H floats) stay in
#: the L2 cache; larger batches run block after block.
KERNEL_ROWS = 256
#: Rows per call of the bf16 kernel: oneDNN's bf16 product costs a fixed preparation per call (the weights'
#: reorder into its blocked layout), which 1024 rows amortise (the products of one step at 512 rows cost 1.2x
#: their time at 1024 per row); its elementwise work runs KERNEL_ROWS rows at a time.
BF16_ROWS = 1024
def _reorder_gates(w: Tensor) -> Tensor:
    """nn.LSTM gate blocks (i, f, g, o) -> (i, f, o, g): one sigmoid covers i, f, o in the roll-out kernels."""
    i, f, g, o = w.chunk(4, 0)
    return torch.cat([i, f, o, g], 0)


def lstm_weights(lstm: nn.LSTM, head: nn.Linear, skip: Optional[nn.Linear]) -> dict[str, Any]:
    """lstm_rollout's weights of an nn.LSTM, its output head and the optional input skip (live tensors: with
    autograd on, gradients flow through them).

    Returns:
        w_x, w_h: per layer the transposed input (6 + F or H, 4 H) and recurrent (H, 4 H) weights; bias: per layer
        the summed biases (4 H,); gates ordered (i, f, o, g). w_out (H, 13), b_out (13,): the head. w_skip: the
        skip's (6, 13), or an empty (0, 13).
    """
    w_x: list[Tensor] = []
    w_h: list[Tensor] = []
    bias: list[Tensor] = []
    for layer in range(lstm.num_layers):
        w_x.append(_reorder_gates(getattr(lstm, f"weight_ih_l{layer}")).t().contiguous())
        w_h.append(_reorder_gates(getattr(lstm, f"weight_hh_l{layer}")).t().contiguous())
        bias.append(_reorder_gates(getattr(lstm, f"bias_ih_l{layer}") + getattr(lstm, f"bias_hh_l{layer}")))
    w_skip = skip.weight.t().contiguous() if skip is not None else head.weight.new_zeros(0, OUT_DIM)
    return {"w_x": w_x, "w_h": w_h, "bias": bias, "w_out": head.weight.t().contiguous(), "b_out": head.bias,
            "w_skip": w_skip}


def kernel_weights(fast: dict[str, Any], cloud_scale: float) -> dict[str, Any]:
    """The inference kernels' weights (fused_lstm_rollout; numpy_lstm_rollout for float32 CPU models), derived
    from lstm_weights' `fast` (with the scale vectors "in", "out", "gain"). All rescalings are by powers of 2
    (exact); only the numpy head's folded feedback (identity + gain * weights) rounds, by one float32 ulp.

    Args:
        fast: lstm_weights' dict with the model's scale vectors.
        cloud_scale: the model's cloud normalisation scale (the numpy prior's lever arm reads it).

    Returns:
        w, b, w_feature, head, b_head, gain for fused_lstm_rollout; for float32 CPU weights also np_w0, np_w,
        np_head, np_w_feature, np_b0, np_in, np_out, np_gain, np_cloud for numpy_rollout and bf16_w, bf16_out,
        bf16_skip, bf16_b_head for bf16_lstm_rollout (bf16_weights).
    """
    w_x, w_h, bias = fast["w_x"], fast["w_h"], fast["bias"]
    w_out, b_out, w_skip = fast["w_out"], fast["b_out"], fast["w_skip"]
    hidden, layers = w_h[0].shape[0], len(w_h)
    # torch kernel: gates (i, f, o, g), g columns doubled (tanh(a) = 2 sigmoid(2 a) - 1)
    two = torch.ones(4 * hidden, dtype=w_out.dtype, device=w_out.device)
    two[3 * hidden:] = 2.0
    w = [torch.cat([w_x[0][:6], w_h[0]], 0) * two] + [torch.cat([w_x[i], w_h[i]], 0) * two
                                                     for i in range(1, layers)]
    head = w_out.new_zeros(6 + layers * hidden, OUT_DIM)
    if w_skip.shape[0]:
        head[:6] = w_skip
    head[6 + (layers - 1) * hidden:] = w_out
    kernel: dict[str, Any] = {
        "w": [m.contiguous() for m in w], "b": [b * two for b in bias],
        "w_feature": (w_x[0][6:] * two).contiguous(), "head": head.contiguous(), "b_head": b_out.contiguous(),
        "gain": fast["gain"].contiguous()}
    if w_out.dtype != torch.float32 or w_out.device.type != "cpu":
        return kernel
    kernel.update(bf16_weights(kernel))
    # numpy kernel (batch 1): gates (o, i, f, g), o/i/f columns halved (sigmoid(a) = (1 + tanh(a / 2)) / 2),
    # h rows halved (z holds 2 h), a bias row before each layer's own h rows: z = [x, 1, h_0, 1, h_1, ...]
    order = torch.cat([torch.arange(2 * hidden, 3 * hidden), torch.arange(0, 2 * hidden),
                       torch.arange(3 * hidden, 4 * hidden)])
    col = torch.ones(4 * hidden)
    col[:3 * hidden] = 0.5

    def gates(m: Tensor) -> np.ndarray:
        return np.ascontiguousarray((m[..., order] * col).numpy(), dtype=np.float32)

    w0 = gates(torch.cat([w_x[0][:6], torch.zeros(1, 4 * hidden), 0.5 * w_h[0]], 0))
    w_np = [gates(torch.cat([0.5 * w_x[i], bias[i][None], 0.5 * w_h[i]], 0)) for i in range(1, layers)]
    size = 6 + layers * (hidden + 1)
    last = 7 + (layers - 1) * (hidden + 1)
    head_np = torch.zeros(size, OUT_DIM + 6)
    if w_skip.shape[0]:
        head_np[:6, :OUT_DIM] = w_skip
    head_np[6, :OUT_DIM] = b_out
    head_np[last:last + hidden, :OUT_DIM] = 0.5 * w_out
    head_np[:, OUT_DIM:] = head_np[:, :6] * fast["gain"]
    head_np[:6, OUT_DIM:] += torch.eye(6)
    kernel.update(packed_weights(w0, w_np))
    kernel.update(np_w0=w0, np_w=w_np, np_head=np.ascontiguousarray(head_np.numpy()),
                  np_w_feature=gates(w_x[0][6:]), np_b0=gates(bias[0]),
                  np_in=fast["in"].numpy().astype(np.float32), np_out=fast["out"].numpy().astype(np.float32),
                  np_gain=fast["gain"].numpy().astype(np.float32), np_cloud=np.float32(cloud_scale))
    return kernel


def bf16_weights(kernel: dict[str, Any]) -> dict[str, Any]:
    """bf16_lstm_rollout's weights from fused_lstm_rollout's (kernel_weights): per layer one bf16 matrix whose rows
    follow its input view of the row buffer, layer 0 [x (6), feature (F), 1 (bias), h_0], layer l
    [h_{l-1}, 1 (bias), h_l]; the head split into its bf16 part on the last h and the float32 input skip.

    Returns:
        bf16_w: list of bf16 (rows, 4 H); bf16_out: (H, 13) bf16; bf16_skip: (6, 13) float32 or empty (0, 13);
        bf16_b_head: (13,) float32.
    """
    w, b, head = kernel["w"], kernel["b"], kernel["head"]
    layers = len(w)
    hidden = w[layers - 1].shape[1] // 4
    low = torch.bfloat16
    stacked = [torch.cat([w[0][:6], kernel["w_feature"], b[0][None], w[0][6:]], 0)]
    stacked += [torch.cat([w[i][:hidden], b[i][None], w[i][hidden:]], 0) for i in range(1, layers)]
    skip = head[:6]
    if not bool(skip.any()):  # a model without input skip: no product of x with zeros
        skip = head.new_zeros(0, OUT_DIM)
    return {"bf16_w": [m.to(low).contiguous() for m in stacked],
            "bf16_out": head[6 + (layers - 1) * hidden:].to(low).contiguous(),
            "bf16_skip": skip.contiguous(), "bf16_b_head": kernel["b_head"].contiguous()}


def lstm_rollout(x0: Tensor, x_obs: Tensor, const0: Tensor, w_x: List[Tensor], w_h: List[Tensor],
                 bias: List[Tensor], w_out: Tensor, b_out: Tensor, w_skip: Tensor, gain: Tensor,
                 steps: int, prior: Tensor, scale_in: Tensor, scale_out: Tensor) -> Tuple[Tensor, Tensor]:
    """Closed-loop LSTM roll-out, compiled by TorchScript: no Python in the loop; differentiable.

    The kernel with autograd on (training with feedback). Without autograd DynamicsModel.rollout_raw runs
    fused_lstm_rollout or, at batch 1 on the CPU, numpy_lstm_rollout: the same function in fewer operations.

    Args:
        x0: (B, 6) normalised [v, w] at frame 0.
        x_obs: (B, K, 6) observed inputs of frames 1..K ("steps in"), fed instead of the model's own.
        const0: (B, 4 H) layer 0's bias plus its shape-feature term (constant over the roll-out).
        w_x, w_h, bias: per layer, the input (6 or H, 4 H) and recurrent (H, 4 H) weights, transposed, and the
            summed biases (4 H,), gates ordered (i, f, o, g) (lstm_weights); w_x[0] without its feature rows.
        w_out, b_out: (H, 13), (13,) the output head.
        w_skip: (6, 13) maps the step's input to the outputs (model.input_skip), or empty (0, 13).
        gain: (6,) normalised output -> increment of the normalised input.
        steps: steps to roll out.
        prior: (B, 3) (mu g, spin deceleration, coupling) of the sliding prior added to the outputs
            (learn/prior.py), or empty (0, 3).
        scale_in, scale_out: (6,), (13,) the normalisation the prior needs.

    Returns:
        Raw outputs (B, steps, 13) and the inputs actually used (B, steps + 1, 6).
    """
    batch = x0.shape[0]
    hidden = w_h[0].shape[0]
    h3 = 3 * hidden
    hs = [torch.zeros(batch, hidden, dtype=x0.dtype, device=x0.device) for _ in range(len(w_h))]
    cs = [torch.zeros(batch, hidden, dtype=x0.dtype, device=x0.device) for _ in range(len(w_h))]
    x = x0
    outs: List[Tensor] = []
    xs: List[Tensor] = [x0]
    for t in range(steps):
        inp = x
        for layer in range(len(w_h)):
            if layer == 0:
                g = torch.addmm(torch.addmm(const0, inp, w_x[0]), hs[0], w_h[0])
            else:
                g = torch.addmm(torch.addmm(bias[layer], inp, w_x[layer]), hs[layer], w_h[layer])
            s = torch.sigmoid(g[:, :h3])
            c = torch.addcmul(s[:, hidden:2 * hidden] * cs[layer], s[:, :hidden], torch.tanh(g[:, h3:]))
            cs[layer] = c
            hs[layer] = s[:, 2 * hidden:h3] * torch.tanh(c)
            inp = hs[layer]
        y = torch.addmm(b_out, inp, w_out)
        if w_skip.shape[0] > 0:
            y = torch.addmm(y, x, w_skip)
        if prior.shape[0] > 0:
            p = prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out)
            y = y + torch.cat([p, torch.zeros_like(p[:, :1])], 1)
        outs.append(y)
        if t < x_obs.shape[1]:
            x = x_obs[:, t]
        else:
            x = torch.addcmul(x, y[:, :6], gain)
        xs.append(x)
    return torch.stack(outs, 1), torch.stack(xs, 1)


def fused_lstm_rollout(x0: Tensor, x_obs: Tensor, const0: Tensor, w: List[Tensor], b: List[Tensor], w_head: Tensor,
                       b_head: Tensor, gain: Tensor, steps: int, prior: Tensor, scale_in: Tensor,
                       scale_out: Tensor) -> Tuple[Tensor, Tensor]:
    """Inference roll-out (no autograd): lstm_rollout's function in fewer operations, allocation-free.

    One matrix product per layer and step: a row buffer z = [x, h_0, ..., h_{L-1}] (B, 6 + L H) holds the step's
    input and every layer's hidden state, so layer 0 multiplies the view [x, h_0] and layer l the view
    [h_{l-1}, h_l] by one stacked weight matrix (w[l]: (6 + H or 2 H, 4 H)), the bias fused into addmm; the head
    (and input_skip) is one product of all of z with w_head (rows of the middle layers zero).
    Elementwise work uses only sigmoid (torch's tanh costs several times its sigmoid per element on a CPU): the
    g-gate columns of w, b and const0 are pre-scaled by 2, so tanh(a) = 2 sigmoid(2 a) - 1, and the cell state is
    kept as c' = -2 c, so that tanh(c) = 1 - 2 sigmoid(c'):
        s = sigmoid(g)                                  (i, f, o, g gates; one call, in place: one (rows, 4 H)
                                                         buffer in the L2 cache instead of two)
        c' <- s_f c' - 4 s_i s_g + 2 s_i                (= -2 (f c + i tanh(g)))
        h  = s_o - 2 s_o sigmoid(c')                    (= o tanh(c))
    Every operation writes into buffers made once.

    Args:
        x0, x_obs, gain, steps, prior, scale_in, scale_out: as lstm_rollout.
        const0: (B, 4 H) as lstm_rollout's, g columns doubled (kernel_weights' b[0] and w_feature).
        w, b: per layer the stacked weights and the biases of kernel_weights.
        w_head, b_head: (6 + L H, 13), (13,) kernel_weights' head over all of z.

    Returns:
        Raw outputs (B, steps, 13) and the inputs used (B, steps + 1, 6).
    """
    batch = x0.shape[0]
    layers = len(w)
    hidden = w[layers - 1].shape[1] // 4
    dtype = x0.dtype
    z = torch.zeros(batch, 6 + layers * hidden, dtype=dtype, device=x0.device)
    z[:, :6] = x0
    x = z[:, :6]
    cs: List[Tensor] = []
    hs: List[Tensor] = []
    zin: List[Tensor] = []
    for layer in range(layers):
        cs.append(torch.zeros(batch, hidden, dtype=dtype, device=x0.device))
        lo = 6 + layer * hidden
        hs.append(z[:, lo:lo + hidden])
        zin.append(z[:, :6 + hidden] if layer == 0 else z[:, lo - hidden:lo + hidden])
    g = torch.empty(batch, 4 * hidden, dtype=dtype, device=x0.device)
    s = g  # the gates in place: one (rows, 4 H) buffer in the cache instead of two
    sc = torch.empty(batch, hidden, dtype=dtype, device=x0.device)
    s_i = s[:, :hidden]
    s_f = s[:, hidden:2 * hidden]
    s_o = s[:, 2 * hidden:3 * hidden]
    s_g = s[:, 3 * hidden:]
    ys = torch.empty(batch, steps, w_head.shape[1], dtype=dtype, device=x0.device)
    xs = torch.empty(batch, steps + 1, 6, dtype=dtype, device=x0.device)
    xs[:, 0] = x0
    observed = x_obs.shape[1]
    for t in range(steps):
        for layer in range(layers):
            if layer == 0:
                torch.addmm(const0, zin[0], w[0], out=g)
            else:
                torch.addmm(b[layer], zin[layer], w[layer], out=g)
            g.sigmoid_()
            c = cs[layer]
            c.mul_(s_f).addcmul_(s_i, s_g, value=-4.0).add_(s_i, alpha=2.0)
            torch.sigmoid(c, out=sc)
            torch.addcmul(s_o, s_o, sc, value=-2.0, out=hs[layer])
        y = ys[:, t]
        torch.addmm(b_head, z, w_head, out=y)
        if prior.shape[0] > 0:  # the sliding prior (model.prior), as in lstm_rollout
            y[:, :12].add_(prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out))
        if t < observed:
            x.copy_(x_obs[:, t])
        else:
            x.addcmul_(y[:, :6], gain)
        xs[:, t + 1] = x
    return ys, xs


def bf16_lstm_rollout(x0: Tensor, x_obs: Tensor, feature: Tensor, w: List[Tensor], w_out: Tensor, w_skip: Tensor,
                      b_head: Tensor, gain: Tensor, steps: int, prior: Tensor, scale_in: Tensor,
                      scale_out: Tensor, chunk: int = 256) -> Tuple[Tensor, Tensor]:
    """fused_lstm_rollout with its matrix products in bfloat16 (fp32 accumulation inside oneDNN) and everything
    that carries state in float32: the gates after their sigmoid, the cell state, the head's input-skip term,
    the prior and the integration of x. Only what enters a product is rounded to bf16: the row buffer and the
    weights.

    Row buffer z = [x, f, 1, h_0, 1, h_1, ...] (bf16): layer 0 multiplies the view [x, f, 1, h_0], layer l the
    view [h_{l-1}, 1, h_l], by one stacked matrix whose 1-rows hold the biases (a plain product: oneDNN's bf16
    addmm pays a pass over the output for its bias; the feature term, constant in time, costs no extra tile
    of the product either). The products' outputs come back in bf16 (torch has no bf16 x bf16 -> fp32 product
    on the CPU) and are widened to fp32 before the sigmoid: a forget gate near 1 rounded to bf16 would be up to
    2^-9 off, and the cell state would forget too fast or too slowly over a long roll-out. Gates as
    fused_lstm_rollout's (g columns doubled, c' = -2 c); the hidden states go straight into z in bf16. The
    products run over all rows at once (oneDNN's bf16 product amortises its per-call preparation over many rows),
    the gates' elementwise work over `chunk` rows at a time through one float32 buffer that stays in the L2
    cache (the gates of 1024 rows in float32, 2 MB, would not).

    Args:
        x0, x_obs, gain, steps, prior, scale_in, scale_out: as lstm_rollout (float32).
        feature: (B, F) float32 shape features.
        w: per layer the stacked bf16 weights (rows [x, f, 1, h_0] for layer 0, [h_{l-1}, 1, h_l] after), gates
            (i, f, o, g), g columns doubled (bf16_weights).
        w_out: (H, 13) bf16, the head on the last layer's h.
        w_skip: (6, 13) float32 input skip (multiplied with the float32 x), or empty (0, 13).
        b_head: (13,) float32.
        chunk: rows of the gates' elementwise work at a time.

    Returns:
        Raw outputs (B, steps, 13) and the inputs used (B, steps + 1, 6), float32.
    """
    batch = x0.shape[0]
    layers = len(w)
    hidden = w[layers - 1].shape[1] // 4
    chunk = max(1, min(chunk, batch))
    device = x0.device
    z, x, cs, hs, zin, g, yh, ys, xs = cell_bf16.row_buffers(x0, feature, w, w_out.shape[1], steps)
    zx = z[:, :6]
    # per chunk of rows: the gates' rows, and per layer the cell state's and the hidden state's rows
    starts = list(range(0, batch, chunk))
    g_rows = [g[r:r + chunk] for r in starts]
    c_rows = [[c[r:r + chunk] for r in starts] for c in cs]
    h_rows = [[h[r:r + chunk] for r in starts] for h in hs]
    s_all = torch.empty(chunk, 4 * hidden, dtype=x0.dtype, device=device)
    sc_all = torch.empty(chunk, hidden, dtype=x0.dtype, device=device)
    # views of the float32 buffers per chunk (the last may be shorter), made once: gates, then i, f, o, g
    s_v = [s_all[:g_rows[j].shape[0]] for j in range(len(starts))]
    sc_v = [sc_all[:g_rows[j].shape[0]] for j in range(len(starts))]
    si_v = [v[:, :hidden] for v in s_v]
    sf_v = [v[:, hidden:2 * hidden] for v in s_v]
    so_v = [v[:, 2 * hidden:3 * hidden] for v in s_v]
    sg_v = [v[:, 3 * hidden:] for v in s_v]
    observed = x_obs.shape[1]
    skip = w_skip.shape[0] > 0
    for t in range(steps):
        for layer in range(layers):
            torch.mm(zin[layer], w[layer], out=g)
            for j in range(len(starts)):
                s = s_v[j]
                s.copy_(g_rows[j])
                s.sigmoid_()
                s_i, s_o, sc = si_v[j], so_v[j], sc_v[j]
                c = c_rows[layer][j]
                c.mul_(sf_v[j]).addcmul_(s_i, sg_v[j], value=-4.0).add_(s_i, alpha=2.0)
                torch.sigmoid(c, out=sc)
                torch.addcmul(s_o, s_o, sc, value=-2.0, out=h_rows[layer][j])
        y = ys[:, t]
        torch.mm(hs[layers - 1], w_out, out=yh)
        if skip:
            torch.addmm(b_head, x, w_skip, out=y)
            y.add_(yh)
        else:
            torch.add(yh, b_head, out=y)
        if prior.shape[0] > 0:
            y[:, :12].add_(prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], scale_in, scale_out))
        if t < observed:
            x.copy_(x_obs[:, t])
        else:
            x.addcmul_(y[:, :6], gain)
        zx.copy_(x)
        xs[:, t + 1] = x
    return ys, xs


def numpy_lstm_rollout(x0: np.ndarray, x_obs: np.ndarray, w0: np.ndarray, w: List[np.ndarray], w_head: np.ndarray,
                       steps: int, prior: Optional[tuple] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Batch-1 roll-out in numpy: the latency path (torch's dispatch costs more than the arithmetic at batch 1,
    and numpy's BLAS multiplies these small matrix-vector products faster).

    Row vector z = [x, 1, h_0, 1, h_1, ...]: the 1 entries carry the biases inside the products. Only tanh is used
    (numpy has no sigmoid; sigmoid(a) = (1 + tanh(a / 2)) / 2), and z stores 2 h = (1 + tanh(a_o / 2)) tanh(c).

    Args:
        x0: (6,) float32 normalised [v, w] at frame 0.
        x_obs: (K, 6) float32 observed inputs of frames 1..K.
        w0: layer 0's weights, rows [x, 1 (bias + shape-feature term), h_0], gate columns (o, i, f, g) with the
            o, i, f columns halved and the h rows halved (numpy_rollout fills the bias row).
        w: the other layers' weights, rows [h_{l-1}, 1, h_l], laid out as w0.
        w_head: (len(z), 19): columns the 13 outputs, then the next input x + gain * outputs[:6] (the feedback
            folded into the product).
        steps: steps to roll out.
        prior: prior.prior_constants of the sliding prior, or None.

    Returns:
        Raw outputs (steps, 13) and the inputs used (steps + 1, 6), float32.
    """
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
        prod = np.empty((2, hidden), np.float32)  # (2 i tanh(g), 2 f c)
        # per layer: product input, weights, gates, (o, i, f) view, (i, f), (g, c), products (2, H) and flat, c,
        # tanh(c), o, h slot
        views.append((inp, w0 if layer == 0 else w[layer - 1], q[:4 * hidden], q[:3 * hidden],
                      q[hidden:3 * hidden], q[3 * hidden:], prod, prod.reshape(-1), q[4 * hidden:],
                      np.empty(hidden, np.float32), q[:hidden], z[lo:lo + hidden]))
    out = np.empty((steps, OUT_DIM + 6), np.float32)
    rows = list(out)
    x = z[:6]
    one = np.float32(1.0)
    halves = np.full(2, 0.5, np.float32)
    dot, tanh, add, mul, copyto = np.dot, np.tanh, np.add, np.multiply, np.copyto
    observed = len(x_obs)
    for t in range(steps):  # 7 numpy calls per layer, outputs passed positionally (cheaper than out=)
        for inp, weights, t4, u3, u_if, g_c, prod, prod_flat, c, tc, u_o, h in views:
            dot(inp, weights, t4)
            tanh(t4, t4)
            add(u3, one, u3)  # 2 sigmoid(a) for o, i, f
            mul(u_if, g_c, prod_flat)  # (2 i tanh(g), 2 f c)
            dot(halves, prod, c)  # c <- (2 i tanh(g) + 2 f c) / 2: the sum and the halving (exact) in one call
            tanh(c, tc)
            mul(u_o, tc, h)  # 2 o tanh(c)
        row = rows[t]
        dot(z, w_head, row)
        if prior is not None:  # the sliding prior: on the outputs and, through the gain, on the next input
            prior_into(row, x, prior)
        if t < observed:
            row[OUT_DIM:] = x_obs[t]
        copyto(x, row[OUT_DIM:])
    xs = np.empty((steps + 1, 6), np.float32)
    xs[0] = x0
    xs[1:] = out[:, OUT_DIM:]
    return out[:, :OUT_DIM], xs


def _compile(fn: Any) -> Any:
    """TorchScript a roll-out kernel: it removes Python from the step loop and, unlike torch.compile, needs no C++
    toolchain or long compilation at load. torch marks TorchScript deprecated; if a future torch drops it, the
    same function runs eagerly (slower, identical results)."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return torch.jit.script(fn)
    except Exception:  # noqa: BLE001 - any scripting failure: run eagerly
        return fn


lstm_rollout = _compile(lstm_rollout)
fused_lstm_rollout = _compile(fused_lstm_rollout)
bf16_lstm_rollout = _compile(bf16_lstm_rollout)


def fused_rollout(kernel: dict[str, Any], feature: Tensor, x0: Tensor, x_obs: Tensor, steps: int, prior: Tensor,
                  scale_in: Tensor, scale_out: Tensor, precision: str = "fp32") -> Tuple[Tensor, Tensor]:
    """fused_lstm_rollout over blocks of KERNEL_ROWS rows on the CPU (a block's gate buffers stay in the L2 cache),
    or with precision "bf16" bf16_lstm_rollout (its cell, head and prior in C where cell_bf16.available) over
    blocks of BF16_ROWS.

    Args:
        kernel: kernel_weights' dict.
        feature: (B, F) shape features.
        x0, x_obs, steps, prior, scale_in, scale_out: as lstm_rollout.
        precision: "fp32" or "bf16" (resolve_precision's; bf16 needs a float32 CPU model's kernel).

    Returns:
        Raw outputs (B, steps, 13) and the inputs used (B, steps + 1, 6).
    """
    if precision == "bf16":
        if "bf16_w" not in kernel:
            raise ValueError("precision bf16 needs a float32 model on the CPU")
        rows = BF16_ROWS
        args = (kernel["bf16_w"], kernel["bf16_out"], kernel["bf16_skip"], kernel["bf16_b_head"], kernel["gain"],
                steps)
        c_cell = cell_bf16.available(kernel["bf16_w"][-1].shape[1] // 4)  # else the TorchScript cell, head and prior
        parts = [cell_bf16.c_bf16_lstm_rollout(x0[i:i + rows], x_obs[i:i + rows], feature[i:i + rows], *args,
                                               prior[i:i + rows] if prior.shape[0] else prior, scale_in,
                                               scale_out) if c_cell else
                 bf16_lstm_rollout(x0[i:i + rows], x_obs[i:i + rows], feature[i:i + rows], *args,
                                   prior[i:i + rows] if prior.shape[0] else prior, scale_in, scale_out, KERNEL_ROWS)
                 for i in range(0, x0.shape[0], rows)]
    elif precision == "fp32":
        const0 = torch.addmm(kernel["b"][0], feature, kernel["w_feature"])
        rows = KERNEL_ROWS if x0.device.type == "cpu" else x0.shape[0]
        parts = [fused_lstm_rollout(x0[i:i + rows], x_obs[i:i + rows], const0[i:i + rows], kernel["w"],
                                    kernel["b"], kernel["head"], kernel["b_head"], kernel["gain"], steps,
                                    prior[i:i + rows] if prior.shape[0] else prior, scale_in, scale_out)
                 for i in range(0, x0.shape[0], rows)]
    else:
        raise ValueError(f"fused_rollout runs in fp32 or bf16, got {precision!r}")
    if len(parts) == 1:
        return parts[0]
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


def numpy_rollout(kernel: dict[str, Any], feature: np.ndarray, x0: np.ndarray, x_obs: np.ndarray, steps: int,
                  prior: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """numpy_lstm_rollout of one object (or the C kernel computing it: native.use_c).

    Args:
        kernel: kernel_weights' dict (of a float32 CPU model).
        feature: (1, F) float32 shape feature.
        x0: (6,), x_obs: (K, 6) float32, as numpy_lstm_rollout.
        steps: steps to roll out.
        prior: (1, 3) (mu g, spin deceleration, coupling) of the sliding prior, or None / empty.

    Returns:
        Raw outputs (steps, 13) and the inputs used (steps + 1, 6), float32.
    """
    bias0 = feature[0] @ kernel["np_w_feature"] + kernel["np_b0"]  # the layer-0 bias row: this object's feature
    args = None
    if prior is not None and len(prior):
        args = prior_constants(prior[0, 0], prior[0, 1], kernel["np_in"], kernel["np_out"], kernel["np_gain"],
                               coupling=float(prior[0, 2]))
    if use_c():  # the same function without numpy's per-call cost
        return c_lstm_rollout(x0, x_obs, bias0, kernel, kernel["np_head"], steps, args)
    w0 = kernel["np_w0"].copy()  # a private copy: the bias row carries this object's feature term
    w0[6] = bias0
    return numpy_lstm_rollout(x0, x_obs, w0, kernel["np_w"], kernel["np_head"], steps, args)


def mlp_rollout(mlp: nn.Module, skip: Optional[nn.Module], feature: Tensor, x0: Tensor, x_obs: Tensor, steps: int,
                prior: Tensor, fast: dict[str, Any]) -> Tuple[Tensor, Tensor]:
    """Closed-loop roll-out of the paper's memoryless MLP baseline (eager; autograd as the caller has it).

    Args:
        mlp: [x, feature] (6 + F) -> raw outputs (13).
        skip: the input skip (6 -> 13) or None.
        feature: (B, F) shape features.
        x0, x_obs, steps, prior: as lstm_rollout.
        fast: the scale vectors "in" (6,), "out" (13,), "gain" (6,).

    Returns:
        Raw outputs (B, steps, 13) and the inputs used (B, steps + 1, 6).
    """
    x, outs, xs = x0, [], [x0]
    for t in range(steps):
        y = mlp(torch.cat([x, feature], -1))
        if skip is not None:
            y = y + skip(x)
        if prior.shape[0] > 0:
            p = prior_raw(x, prior[:, 0], prior[:, 1], prior[:, 2], fast["in"], fast["out"])
            y = y + torch.cat([p, torch.zeros_like(p[:, :1])], 1)
        outs.append(y)
        x = x_obs[:, t] if t < x_obs.shape[1] else x + y[:, :6] * fast["gain"]
        xs.append(x)
    return torch.stack(outs, 1), torch.stack(xs, 1)
