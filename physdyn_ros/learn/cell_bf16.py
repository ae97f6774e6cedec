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
"""The bf16 batched roll-out with its elementwise work in C (src/cell_bf16.c, in the C kernels' library that
native.py loads): kernels.bf16_lstm_rollout's function, its products still oneDNN's. Per step and layer one AVX-512
pass runs the cell (seven torch passes over the gates there); after the last layer's cell the same pass finishes
each row: the head (a bf16 product whose output torch would round to bf16; here its dot products accumulate in
float32), the sliding prior and the next input (two dozen small torch operations). Used where the CPU reports
avx512f, avx512bw and avx512_bf16 and the library was built with them (available()); kernels.fused_rollout falls
back to the TorchScript kernel elsewhere. It is that kernel up to float32 rounding of the sigmoids and the prior
(and the bf16 rounding of h that such a difference can flip) and the head's unrounded output: test_precision
holds it at least as close to float32.
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

#: The head's outputs per step the C step tail takes (kernels.OUT_DIM; src/cell_bf16.c's TAIL_OUT).
TAIL_OUT = 13

#: The CPU flags the cell is compiled for (as lscpu names them).
FLAGS = frozenset({"avx512f", "avx512bw", "avx512_bf16"})
#: The cell's vector width in hidden units: other hidden sizes run the TorchScript kernel.
WIDTH = 16


class Tail(ctypes.Structure):
    """src/cell_bf16.c's physdyn_tail: the operands of a step's tail (the head, the prior, the next input)."""
    _fields_ = [("w_pairs", ctypes.c_void_p), ("w_skip", ctypes.c_void_p), ("b_head", ctypes.c_void_p),
                ("prior", ctypes.c_void_p), ("p_stride", ctypes.c_int64), ("scale_in", ctypes.c_void_p),
                ("scale_out", ctypes.c_void_p), ("dt", ctypes.c_float), ("x_obs", ctypes.c_void_p),
                ("obs_stride", ctypes.c_int64), ("gain", ctypes.c_void_p), ("x", ctypes.c_void_p),
                ("x_stride", ctypes.c_int64), ("y", ctypes.c_void_p), ("y_stride", ctypes.c_int64),
                ("xs", ctypes.c_void_p), ("xs_stride", ctypes.c_int64), ("zx", ctypes.c_void_p),
                ("z_stride", ctypes.c_int64)]


@lru_cache(maxsize=1)
def _cell() -> Tuple[Optional[Tuple[Callable[..., int], Callable[..., int]]], str]:
    """(the cell, the last layer's cell with the step tail) from the library, or None and why not."""
    lib, why = library()
    if lib is None:
        return None, why
    try:
        simd, fn, last = lib.physdyn_cell_bf16_simd, lib.physdyn_lstm_cell_bf16, lib.physdyn_cell_tail_bf16
        size = lib.physdyn_tail_size
    except AttributeError as exc:  # a library built before the cell (or its step tail) existed
        return None, str(exc)
    size.restype = ctypes.c_int64
    if size() != ctypes.sizeof(Tail):
        return None, f"the library's step tail struct has {size()} bytes, its Python mirror {ctypes.sizeof(Tail)}"
    if not simd():
        return None, "the C kernels' library was built without AVX-512 BF16 (a compiler without -mavx512bf16)"
    if not FLAGS <= cpu_flags():
        return None, f"the CPU lacks {', '.join(sorted(FLAGS - cpu_flags()))}"
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    fn.restype = last.restype = ctypes.c_int
    fn.argtypes = [ptr, i64, ptr, i64, ptr, i64, i64, i64]
    last.argtypes = fn.argtypes + [ctypes.POINTER(Tail)]
    return (fn, last), "the C cell (AVX-512 BF16)"


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
    """kernels.bf16_lstm_rollout (its arguments but `chunk`, its row buffer and weights) with the cells and the
    step's tail in C; the step loop runs in Python (two calls per layer a step, against milliseconds of products
    at the batches that run in bf16)."""
    found, why = _cell()
    batch, layers = x0.shape[0], len(w)
    hidden = w[layers - 1].shape[1] // 4
    if found is None or hidden % WIDTH:
        raise RuntimeError(f"the C cell cannot run: {why if found is None else f'hidden size {hidden}'}")
    cell, last = found
    z, x, cs, hs, zin, g, _, ys, xs = row_buffers(x0, feature, w, w_out.shape[1], steps)
    if w_out.shape[1] != TAIL_OUT:
        raise ValueError(f"the C step tail takes a head of {TAIL_OUT} outputs, got {w_out.shape[1]}")
    observed, has_prior = x_obs.shape[1], prior.shape[0] > 0
    calls = [(g.data_ptr(), g.stride(0), cs[i].data_ptr(), cs[i].stride(0), hs[i].data_ptr(), z.stride(0), batch,
              hidden) for i in range(layers)]
    # the tail's operands, padded to 16 output lanes: the head's weights as pairs of rows (k, k + 1) per column,
    # what an AVX-512 BF16 dot product multiplies with a pair of h
    w_pairs = torch.zeros(hidden // 2, 16, 2, dtype=torch.bfloat16)
    w_pairs[:, :TAIL_OUT] = w_out.to(torch.bfloat16).reshape(hidden // 2, 2, TAIL_OUT).transpose(1, 2)
    skip16 = None
    if w_skip.shape[0] > 0:
        skip16 = torch.zeros(6, 16)
        skip16[:, :TAIL_OUT] = w_skip
    b16 = torch.zeros(16)
    b16[:TAIL_OUT] = b_head
    gain = gain.to(torch.float32).contiguous()
    x_obs = x_obs.to(torch.float32).contiguous()
    tail = Tail(w_pairs=w_pairs.data_ptr(), w_skip=None if skip16 is None else skip16.data_ptr(),
                b_head=b16.data_ptr(), dt=DT, obs_stride=x_obs.stride(0), gain=gain.data_ptr(), x=x.data_ptr(),
                x_stride=x.stride(0), y_stride=ys.stride(0), xs_stride=xs.stride(0), zx=z.data_ptr(),
                z_stride=z.stride(0))
    if x.dtype != torch.float32:  # the tail writes x, ys and xs as float32
        raise ValueError(f"the C step tail needs float32 inputs, got {x.dtype}")
    if has_prior:  # float32, contiguous rows: what the C prior reads
        if prior.shape != (batch, 3) or scale_in.numel() < 6 or scale_out.numel() < 12:
            raise ValueError(f"the C prior needs a ({batch}, 3) prior, 6 input and 12 output scales, got "
                             f"{tuple(prior.shape)}, {scale_in.numel()} and {scale_out.numel()}")
        prior = prior.to(torch.float32).contiguous()
        scale_in, scale_out = (s.to(torch.float32).contiguous() for s in (scale_in, scale_out))
        tail.prior, tail.p_stride = prior.data_ptr(), prior.stride(0)
        tail.scale_in, tail.scale_out = scale_in.data_ptr(), scale_out.data_ptr()
    tail_ref = ctypes.byref(tail)
    y_ptr, y_step = ys.data_ptr(), ys.stride(1) * ys.element_size()
    xs_ptr, xs_step = xs.data_ptr(), xs.stride(1) * xs.element_size()
    obs_ptr, obs_step = x_obs.data_ptr(), x_obs.stride(1) * x_obs.element_size()
    for t in range(steps):
        for layer in range(layers - 1):
            torch.mm(zin[layer], w[layer], out=g)
            cell(*calls[layer])
        torch.mm(zin[layers - 1], w[layers - 1], out=g)
        tail.y, tail.xs = y_ptr + t * y_step, xs_ptr + (t + 1) * xs_step
        tail.x_obs = obs_ptr + t * obs_step if t < observed else None
        last(*calls[layers - 1], tail_ref)
    return ys, xs
