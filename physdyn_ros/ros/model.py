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
"""Loading the Predictor inside a node: once, at start, with explicit torch threads (Predictor.load warms up)."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Sequence

from rclpy.node import Node

if TYPE_CHECKING:  # torch is imported only when a node actually loads a model
    from ..predictor import Predictor


class ModelLoadError(RuntimeError):
    """The checkpoint cannot be used; the node must not start."""


def check_device(device: str) -> None:
    """ModelLoadError unless torch can use `device` here (a CUDA index this machine does not have, a typo)."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise ModelLoadError(f"device {device!r} is not a torch device (cpu, cuda, cuda:N): {exc}") from None
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ModelLoadError(f"device {device!r}: torch sees no CUDA device on this machine (use cpu)")
        if dev.index is not None and dev.index >= count:
            raise ModelLoadError(f"device {device!r}: torch sees {count} CUDA device(s), cuda:0-cuda:{count - 1}")
    elif dev.type != "cpu":
        raise ModelLoadError(f"device {device!r}: only cpu and cuda devices are supported")


def load_predictor(node: Node, model_path: str, device: str, num_threads: int,
                   precision: str = "auto", topple_fusion: bool = False, friction: float = 0.5) -> "Predictor":
    """Predictor.load(model_path or the shipped default) with torch.set_num_threads(num_threads), the precision of
    its batched roll-outs (auto, fp32, bf16), the topple fusion with physics at `friction` when asked, and its
    warm-up roll-outs done before the first request. Raises ModelLoadError with the reason."""
    from ..learn import native
    from ..predictor import Predictor

    t0 = time.monotonic()
    where = model_path or "the shipped default model"
    check_device(device)
    try:
        # Explicit threads: torch would otherwise start one per core in every node and oversubscribe the machine.
        predictor = Predictor.load(model_path or None, device=device, threads=max(1, int(num_threads)),
                                   precision=precision, topple_fusion=topple_fusion, friction=friction)
        batch1 = "the C kernel" if native.use_c() else "numpy"  # ValueError for a wrong PHYSDYN_BATCH1_KERNEL
    except Exception as exc:  # noqa: BLE001 - missing, corrupt or incompatible: the node refuses to start
        raise ModelLoadError(f"cannot load model from {where}: {exc}") from exc
    node.get_logger().info(f"model {predictor.model_id} loaded from {predictor.path} on {device} "
                           f"({num_threads} torch threads, large batches in {predictor.batch_precision(1 << 20)}, "
                           f"batch 1 in {batch1}{', topples fused with physics' if topple_fusion else ''}) "
                           f"in {time.monotonic() - t0:.2f} s")
    return predictor


def load_ensemble(node: Node, size: int, paths: Sequence[str], model_path: str, device: str, num_threads: int,
                  precision: str = "auto") -> list["Predictor"]:
    """The further members of a `size`-model ensemble, the node's model its first (resources.ensemble_paths: the
    `paths` given, else the shipped members with the shipped model; size 0: all of them), loaded like the model.
    Raises ModelLoadError with the reason (too few members, one that cannot be loaded)."""
    from ..predictor import Predictor
    from ..resources import ensemble_paths

    try:
        found = ensemble_paths(size, model_path, paths)
    except ValueError as exc:
        raise ModelLoadError(f"plan_ensemble {size}: {exc}") from None
    t0 = time.monotonic()
    members = []
    for path in found:
        try:
            members.append(Predictor.load(path, device=device, threads=max(1, int(num_threads)), precision=precision))
        except Exception as exc:  # noqa: BLE001 - missing, corrupt or incompatible: the node refuses to start
            raise ModelLoadError(f"cannot load ensemble member {path}: {exc}") from exc
    if members:
        node.get_logger().info(f"plan_push's robustness check over {1 + len(members)} models: the model and "
                               f"{', '.join(m.model_id for m in members)} ({time.monotonic() - t0:.2f} s)")
    return members
