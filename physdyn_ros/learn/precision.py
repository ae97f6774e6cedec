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
"""The precision of batched roll-outs: what the CPU reports, and which precision a batch runs in.

bf16 matrix products (with float32 accumulation and state, learn/kernels.py) pay only where the CPU has bf16
arithmetic; elsewhere torch emulates them, slower than float32.
"""
from __future__ import annotations

import functools
import os
from typing import FrozenSet, Optional

import torch

#: Roll-out precisions: "auto" picks bf16 where the CPU has bf16 arithmetic (cpu_has_bf16) and the batch has at
#: least AUTO_BF16_ROWS rows, else fp32; "fp32" and "bf16" force one.
PRECISIONS = ("auto", "fp32", "bf16")
#: The smallest batch "auto" runs in bf16: below it the bf16 kernel is no faster than the float32 one (the fixed
#: cost of oneDNN's bf16 product per call outweighs its arithmetic; measured on one Sapphire Rapids core, the
#: shipped model, 60 steps: 16 rows 0.72x, 64 rows 0.88x, 128 rows 1.11x, 256 rows 1.41x, 1024 rows 2.34x the
#: float32 kernel's speed), so small batches keep their float32 results.
AUTO_BF16_ROWS = 128
#: CPU flags (as /proc/cpuinfo and lscpu name them) of bf16 arithmetic: AVX-512 BF16 dot products, AMX tiles.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")
#: Caps of oneDNN's instruction set (the environment variable ONEDNN_MAX_CPU_ISA, or the older DNNL_MAX_CPU_ISA)
#: below bf16 arithmetic: under one of them oneDNN runs bf16 products without the CPU's bf16 instructions, about
#: 100x slower than float32 (bench/bench_predictor.py, one Sapphire Rapids core, ONEDNN_MAX_CPU_ISA=AVX2).
NO_BF16_ISA_CAPS = ("SSE41", "AVX", "AVX2", "AVX2_VNNI", "AVX2_VNNI_2", "AVX512_CORE", "AVX512_CORE_VNNI")
#: Flags the benchmark reports (what the kernels' libraries can use).
REPORTED_FLAGS = ("avx2", "fma", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16")


@functools.lru_cache(maxsize=1)
def cpu_flags() -> FrozenSet[str]:
    """The CPU's feature flags from /proc/cpuinfo (Linux; what lscpu prints), or, elsewhere, the bf16 flags
    torch's own CPU probe confirms."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    probes = {"avx512_bf16": "_is_avx512_bf16_supported", "amx_bf16": "_is_amx_tile_supported",
              "avx2": "_is_avx2_supported", "avx512f": "_is_avx512_supported"}
    found = set()
    for flag, probe in probes.items():
        try:
            if getattr(torch.cpu, probe)():
                found.add(flag)
        except Exception:  # noqa: BLE001 - a private probe a torch version lacks: the flag is unknown, not set
            pass
    return frozenset(found)


def isa_cap() -> Optional[str]:
    """oneDNN's instruction-set cap from the environment (upper case), or None where none is set."""
    for name in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        value = os.environ.get(name, "").strip().upper()
        if value:
            return value
    return None


def cpu_has_bf16() -> bool:
    """True where the CPU reports bf16 arithmetic (BF16_FLAGS) and oneDNN may use it (no NO_BF16_ISA_CAPS cap):
    there bf16 products run several times faster than float32 ones; elsewhere they are emulated, slower than
    float32."""
    if isa_cap() in NO_BF16_ISA_CAPS:
        return False
    flags = cpu_flags()
    return any(flag in flags for flag in BF16_FLAGS)


def check_precision(precision: str) -> str:
    """`precision` if it is one of PRECISIONS, else ValueError naming them."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return precision


def resolve_precision(precision: str, device: str = "cpu", rows: Optional[int] = None) -> str:
    """The precision a batched roll-out of `rows` rows (None: a large batch) runs in, "fp32" or "bf16": "auto" is
    bf16 on a CPU that reports bf16 arithmetic for batches of at least AUTO_BF16_ROWS, fp32 otherwise and on
    other devices; "bf16" forced on another device is refused (the bf16 kernel's weights are made for CPU
    models)."""
    check_precision(precision)
    on_cpu = str(device).split(":")[0] == "cpu"
    if precision == "auto":
        large = rows is None or rows >= AUTO_BF16_ROWS
        return "bf16" if on_cpu and large and cpu_has_bf16() else "fp32"
    if precision == "bf16" and not on_cpu:
        raise ValueError(f"precision bf16 runs on the CPU only, not on device {device!r} (use fp32 or auto)")
    return precision
