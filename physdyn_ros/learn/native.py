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
"""The batch-1 roll-out kernel in C (src/rollout1.c, built by CMakeLists.txt into <prefix>/lib): the same function
as kernels.numpy_lstm_rollout without numpy's per-call cost, equal to it up to float32 rounding.

Which kernel batch 1 runs: the environment variable PHYSDYN_BATCH1_KERNEL, "auto" (default: the C kernel where it
is built and the CPU has what it was compiled for, else numpy), "numpy" or "c" (an error where it cannot load).
"""
from __future__ import annotations

import ctypes
import os
import sys
from functools import lru_cache
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np

from .precision import cpu_flags

ENV = "PHYSDYN_BATCH1_KERNEL"
CHOICES = ("auto", "numpy", "c")
LIBRARY = "libphysdyn_rollout1.so"
PANEL = 64  # src/rollout1.c's PANEL
COLS = 19  # the head's columns: the 13 raw outputs, then the next input (6)
_FLOAT_P = ctypes.POINTER(ctypes.c_float)


def library_paths() -> List[Path]:
    """Where the library may be: the interpreter's prefix (setup.sh installs into .venv/lib) and each
    AMENT_PREFIX_PATH entry's lib/ (a colcon workspace)."""
    prefixes = [sys.prefix] + [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return [Path(p) / "lib" / LIBRARY for p in dict.fromkeys(prefixes)]


@lru_cache(maxsize=1)
def library() -> Tuple[Optional[ctypes.CDLL], str]:
    """The C kernels' library (loaded once; cell_bf16 finds its symbols there too), or None and why not."""
    why = []
    for path in library_paths():
        if not path.is_file():
            continue
        try:  # a stale or foreign build (no such symbols) is passed over like a missing one
            lib = ctypes.CDLL(str(path))
            simd, fn = lib.physdyn_rollout1_simd, lib.physdyn_rollout1
        except (OSError, AttributeError) as exc:
            why.append(f"{path}: {exc}")
            continue
        if simd() and not {"avx2", "fma"} <= cpu_flags():
            why.append(f"{path} is built for AVX2 and FMA, which this CPU lacks")
            continue
        fn.restype = ctypes.c_int
        fn.argtypes = [_FLOAT_P, _FLOAT_P, ctypes.c_int, _FLOAT_P, _FLOAT_P, ctypes.POINTER(_FLOAT_P), ctypes.c_int,
                       ctypes.c_int, _FLOAT_P, ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_double),
                       _FLOAT_P]
        return lib, str(path)
    return None, "; ".join(why) or (f"{LIBRARY} is not built (looked in "
                                    f"{', '.join(str(p.parent) for p in library_paths())})")


def status() -> str:
    """Where the C kernel was loaded from, or why it is not used."""
    return library()[1]


def use_c() -> bool:
    """Whether batch 1 runs the C kernel (PHYSDYN_BATCH1_KERNEL; ValueError for an unknown value, or for "c"
    where the library cannot load)."""
    choice = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if choice not in CHOICES:
        raise ValueError(f"{ENV}={choice!r}: expected one of {', '.join(CHOICES)}")
    if choice == "numpy":
        return False
    lib, why = library()
    if lib is None and choice == "c":
        raise ValueError(f"{ENV}=c, but the C kernel cannot load: {why}")
    return lib is not None


def _ptr(a: np.ndarray) -> "ctypes._Pointer":
    return a.ctypes.data_as(_FLOAT_P)


def pack(w: np.ndarray) -> np.ndarray:
    """A (k, n) float32 matrix as the C kernel reads it: column panels of PANEL columns (the last one narrower),
    each panel's k rows contiguous."""
    w = np.asarray(w, np.float32)
    return np.ascontiguousarray(np.concatenate([w[:, j:j + PANEL].reshape(-1) for j in range(0, w.shape[1], PANEL)]))


def packed_weights(w0: np.ndarray, w: List[np.ndarray]) -> dict:
    """The C kernel's copies of numpy_lstm_rollout's layer weights (kernels.kernel_weights keeps them)."""
    return {"c_w0": pack(w0), "c_w": [pack(m) for m in w], "c_hidden": w0.shape[1] // 4}


def c_lstm_rollout(x0: np.ndarray, x_obs: np.ndarray, bias0: np.ndarray, packed: dict, w_head: np.ndarray,
                   steps: int, prior: Optional[tuple] = None) -> Tuple[np.ndarray, np.ndarray]:
    """kernels.numpy_lstm_rollout computed by the C kernel (use_c() must be true): its x0, x_obs, w_head, steps
    and prior; its w0 and w as packed_weights, with w0's bias row (the object's feature term) as bias0 (4 H,)."""
    lib, why = library()
    if lib is None:
        raise RuntimeError(f"the C kernel cannot load: {why}")
    hidden, layer_w = int(packed["c_hidden"]), packed["c_w"]
    layers, cols = len(layer_w) + 1, w_head.shape[1]
    x0_c, obs_c, bias_c = (np.ascontiguousarray(a, np.float32) for a in (x0, x_obs, bias0))
    if (packed["c_w0"].size != (7 + hidden) * 4 * hidden or w_head.shape != (6 + layers * (hidden + 1), COLS)
            or any(m.size != (2 * hidden + 1) * 4 * hidden for m in layer_w) or x0_c.shape != (6,)
            or bias_c.shape != (4 * hidden,) or obs_c.shape[1:] != (6,) or w_head.dtype != np.float32
            or not w_head.flags.c_contiguous):
        raise ValueError("c_lstm_rollout: the weights' shapes do not fit numpy_lstm_rollout's layout")
    layer_ptrs = (_FLOAT_P * max(len(layer_w), 1))(*[_ptr(m) for m in layer_w])
    c_prior = None if prior is None else (ctypes.c_double * 16)(*[float(v) for v in prior])
    out = np.empty((steps, cols), np.float32)
    rc = lib.physdyn_rollout1(_ptr(x0_c), _ptr(obs_c), int(len(obs_c)), _ptr(packed["c_w0"]), _ptr(bias_c),
                              layer_ptrs, layers, hidden, _ptr(w_head), cols, int(steps), c_prior, _ptr(out))
    if rc != 0:
        raise RuntimeError(f"physdyn_rollout1 refused its arguments ({rc})")
    xs = np.empty((steps + 1, 6), np.float32)
    xs[0] = x0_c
    xs[1:] = out[:, cols - 6:]
    return out[:, :cols - 6], xs
