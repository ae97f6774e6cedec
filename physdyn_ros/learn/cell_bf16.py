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
"""The bf16 batched roll-out with its LSTM cell and sliding prior in C (src/cell_bf16.c, in the C kernels' library
that native.py loads): kernels.bf16_lstm_rollout's function, its products still oneDNN's, the elementwise cell step
(seven torch passes over the gates there) one AVX-512 pass, the prior (two dozen small torch operations) one loop.
Used where the CPU reports avx512f, avx512bw and avx512_bf16 and the library was built with them (available());
kernels.fused_rollout falls back to the TorchScript kernel elsewhere. Equal to the TorchScript kernel up to float32
rounding of the sigmoids and the prior (and the bf16 rounding of h that such a difference can flip), which
test_precision bounds.
"""
from __future__ import annotations

import ctypes
from functools import lru_cache
from typing import Callable, List, Optional, Tuple

import torch
from torch import Tensor

from .native import library
from .precision import cpu_flags
from ..conventions import DT

#: The CPU flags the cell is compiled for (as lscpu names them).
FLAGS = frozenset({"avx512f", "avx512bw", "avx512_bf16"})
#: The cell's vector width in hidden units: other hidden sizes run the TorchScript kernel.
WIDTH = 16


@lru_cache(maxsize=1)
def _cell() -> Tuple[Optional[Tuple[Callable[..., int], Callable[..., None]]], str]:
    """(the cell, the prior) from the library, or None and why not."""
    lib, why = library()
    if lib is None:
        return None, why
    try:
        simd, fn, prior = lib.physdyn_cell_bf16_simd, lib.physdyn_lstm_cell_bf16, lib.physdyn_prior_add_f32
    except AttributeError as exc:  # a library built before the cell existed
        return None, str(exc)
    if not simd():
        return None, "the C kernels' library was built without AVX-512 BF16 (a compiler without -mavx512bf16)"
    if not FLAGS <= cpu_flags():
        return None, f"the CPU lacks {', '.join(sorted(FLAGS - cpu_flags()))}"
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p,
                   ctypes.c_int64, ctypes.c_int64, ctypes.c_int64]
    prior.restype = None
    prior.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p,
                      ctypes.c_void_p, ctypes.c_float, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64]
    return (fn, prior), "the C cell (AVX-512 BF16)"


def available(hidden: int) -> bool:
    """Whether c_bf16_lstm_rollout runs here for a model of `hidden` units."""
    return _cell()[0] is not None and hidden % WIDTH == 0


def status() -> str:
    """Which cell the bf16 kernel uses, or why not the C one."""
    return _cell()[1]


def row_buffers(x0: Tensor, feature: Tensor, w: List[Tensor], outputs: int, steps: int) -> Tuple[
        Tensor, Tensor, List[Tensor], List[Tensor], List[Tensor], Tensor, Tensor, Tensor, Tensor]:
    """The buffers of a bf16 roll-out (kernels.bf16_lstm_rollout's and c_bf16_lstm_rollout's; TorchScript
    compiles it into the former): z, the bf16 row buffer [x, feature, 1, h_0, 1, h_1, ...] whose slices are the
    products' inputs; x, the float32 input (z[:, :6] its bf16 copy); per layer the float32 cell state, h (a view
    into z) and the product's input (a view into z); the bf16 gates (B, 4 H) and head product (B, outputs); the
    outputs (B, steps, outputs) and inputs (B, steps + 1, 6), float32, the first input x0."""
    batch, layers = x0.shape[0], len(w)
    hidden = w[layers - 1].shape[1] // 4
    features = feature.shape[1]
    low, device = w[0].dtype, x0.device
    z = torch.zeros(batch, 7 + features + layers * (hidden + 1) - 1, dtype=low, device=device)
    x = x0.clone(memory_format=torch.contiguous_format)  # rows of 6: what the C prior reads
    z[:, :6] = x
    z[:, 6:6 + features] = feature
    cs: List[Tensor] = []
    hs: List[Tensor] = []
    zin: List[Tensor] = []
    for layer in range(layers):
        cs.append(torch.zeros(batch, hidden, dtype=x0.dtype, device=device))
        lo = 7 + features + layer * (hidden + 1)  # this layer's h; its 1 column just before it
        z[:, lo - 1] = 1.0
        hs.append(z[:, lo:lo + hidden])
        zin.append(z[:, :lo + hidden] if layer == 0 else z[:, lo - 1 - hidden:lo + hidden])
    g = torch.empty(batch, 4 * hidden, dtype=low, device=device)
    yh = torch.empty(batch, outputs, dtype=low, device=device)
    ys = torch.empty(batch, steps, outputs, dtype=x0.dtype, device=device)
    xs = torch.empty(batch, steps + 1, 6, dtype=x0.dtype, device=device)
    xs[:, 0] = x0
    return z, x, cs, hs, zin, g, yh, ys, xs


def c_bf16_lstm_rollout(x0: Tensor, x_obs: Tensor, feature: Tensor, w: List[Tensor], w_out: Tensor,
                        w_skip: Tensor, b_head: Tensor, gain: Tensor, steps: int, prior: Tensor, scale_in: Tensor,
                        scale_out: Tensor) -> Tuple[Tensor, Tensor]:
    """kernels.bf16_lstm_rollout (its arguments but `chunk`, its row buffer and weights) with the cell and the
    sliding prior in C; the step loop runs in Python (a dozen calls a step, against milliseconds of products at
    the batches that run in bf16)."""
    found, why = _cell()
    batch, layers = x0.shape[0], len(w)
    hidden = w[layers - 1].shape[1] // 4
    if found is None or hidden % WIDTH:
        raise RuntimeError(f"the C cell cannot run: {why if found is None else f'hidden size {hidden}'}")
    cell, prior_add = found
    z, x, cs, hs, zin, g, yh, ys, xs = row_buffers(x0, feature, w, w_out.shape[1], steps)
    zx = z[:, :6]
    observed, skip, has_prior = x_obs.shape[1], w_skip.shape[0] > 0, prior.shape[0] > 0
    calls = [(g.data_ptr(), g.stride(0), cs[i].data_ptr(), cs[i].stride(0), hs[i].data_ptr(), z.stride(0), batch,
              hidden) for i in range(layers)]
    if has_prior:  # float32, contiguous rows: what the C prior reads
        if x.dtype != torch.float32 or prior.shape != (batch, 3) or scale_in.numel() < 6 or scale_out.numel() < 12:
            raise ValueError(f"the C prior needs float32 inputs and a ({batch}, 3) prior, got {x.dtype} and "
                             f"{tuple(prior.shape)}")
        prior = prior.to(torch.float32).contiguous()
        scale_in, scale_out = (s.to(torch.float32).contiguous() for s in (scale_in, scale_out))
        prior_call = (x.data_ptr(), x.stride(0), prior.data_ptr(), prior.stride(0), scale_in.data_ptr(),
                      scale_out.data_ptr(), DT)
    for t in range(steps):
        for layer in range(layers):
            torch.mm(zin[layer], w[layer], out=g)
            cell(*calls[layer])
        y = ys[:, t]
        torch.mm(hs[layers - 1], w_out, out=yh)
        if skip:
            torch.addmm(b_head, x, w_skip, out=y)
            y.add_(yh)
        else:
            torch.add(yh, b_head, out=y)
        if has_prior:
            prior_add(*prior_call, y.data_ptr(), y.stride(0), batch)
        if t < observed:
            x.copy_(x_obs[:, t])
        else:
            x.addcmul_(y[:, :6], gain)
        zx.copy_(x)
        xs[:, t + 1] = x
    return ys, xs
