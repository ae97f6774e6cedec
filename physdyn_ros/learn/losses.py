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
"""The paper's relative losses (Eq. 1), made safe at zero.

relative_to "target" (the paper's form, with eps):
    L_x   = ||x_hat - x||_2 / (||x||_2 + eps)                  for d_vel, d_angvel, d_pos
    L_rot = ||r_hat - r||_1 / (||r||_1 + eps)                  for the axis-angle increment
relative_to "both" (symmetric):
    L_x   = ||x_hat - x||_2 / (||x_hat||_2 + ||x||_2 + eps),   L_rot likewise with L1 norms
then
    L_cls = BCE(topple logit, label)
    L     = w_v L_v + w_w L_w + w_p L_p + w_rot L_rot + w_cls L_cls   (paper: all 1, w_cls = 2)
    (+ w_abs L_abs, the absolute error in normalised units; off by default)

Relative errors weigh a slow object's small increments as much as a fast one's large ones (the paper's
reason). The original had no eps, so a resting object (both vectors exactly 0) gave 0/0 = NaN; with eps the
loss is 0 there. At a zero target (an object at rest) the "target" form is ||x_hat|| / eps, a firm L1 pull
towards rest; the symmetric form saturates at ~1 with a vanishing gradient once ||x_hat|| >> eps, so a model
trained with it learns no pull to rest and its roll-outs keep drifting after the object stopped (their rotation
error grows steadily with time). The shipped configs use "target".
The norm's gradient at 0 is defined as 0, so identical prediction and target give a zero, finite gradient.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from .sections import known_keys

#: Terms beyond the paper's, each on when its weight w_<name> is > 0.
OPTIONAL_TERMS = ("abs",)
#: (name, slice of the 12 normalised increments)
COMPONENTS = (("vel", slice(0, 3)), ("angvel", slice(3, 6)), ("pos", slice(6, 9)), ("rot", slice(9, 12)))


@dataclass
class LossConfig:
    """Weights and the stabilising epsilon (the `loss:` section of a config YAML)."""

    w_vel: float = 1.0
    w_angvel: float = 1.0
    w_pos: float = 1.0
    w_rot: float = 1.0
    w_topple: float = 2.0
    eps: float = 1e-3  # in normalised units (increments are ~1 there)
    relative_to: str = "both"  # "target" (paper: divide by ||x|| + eps) or "both" (||x_hat|| + ||x|| + eps)
    # Beyond the paper: w_abs * the absolute error in normalised units (L2, L1 for rot), summed over the four
    # increments. A relative loss gives a fast object's large increment a gradient ~1/||x|| as small as a
    # resting one's is large, so the few steps that carry most of a hard push's travel are under-weighted.
    w_abs: float = 0.0
    # Models with a centre-of-mass head (model.com_head): w_com * the L2 error of the estimate in cloud-scale units.
    w_com: float = 1.0

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "LossConfig":
        data = known_keys(cls, data, "loss")
        values: dict[str, Any] = {k: (str(v) if k == "relative_to" else float(v)) for k, v in data.items()}
        cfg = cls(**values)
        if cfg.relative_to not in ("both", "target"):
            raise ValueError(f"loss.relative_to must be 'both' or 'target', got {cfg.relative_to!r}")
        if cfg.eps <= 0 or min(v for k, v in asdict(cfg).items() if k.startswith("w_")) < 0:
            raise ValueError("loss.eps must be > 0 and the loss weights >= 0")
        return cfg

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def safe_l2(x: Tensor) -> Tensor:
    """Euclidean norm over the last dim whose gradient at 0 is 0 (torch's sqrt would give NaN)."""
    sq = (x * x).sum(-1)
    nonzero = sq > 0
    return torch.where(nonzero, torch.sqrt(torch.where(nonzero, sq, torch.ones_like(sq))), torch.zeros_like(sq))


def relative_l2(pred: Tensor, target: Tensor, eps: float, symmetric: bool = True) -> Tensor:
    """Per-vector relative L2 error (...,) of (..., 3) vectors."""
    scale = safe_l2(target) + eps + (safe_l2(pred) if symmetric else 0.0)
    return safe_l2(pred - target) / scale


def relative_l1(pred: Tensor, target: Tensor, eps: float, symmetric: bool = True) -> Tensor:
    """Per-vector relative L1 error (...,) of (..., 3) vectors (abs has subgradient 0 at 0)."""
    scale = target.abs().sum(-1) + eps + (pred.abs().sum(-1) if symmetric else 0.0)
    return (pred - target).abs().sum(-1) / scale


def dynamics_loss(raw: Tensor, target: Tensor, topple: Tensor, cfg: LossConfig,
                  mask: Tensor | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """Total loss and its components (detached) for raw outputs (B, T, 13).

    target: normalised increments (B, T, 12) (DynamicsModel.normalize_targets); topple: labels (B, T) in {0, 1};
    mask: optional (B, T) weights (1 = counted), e.g. to drop steps past the end of a short sequence.
    """
    if raw.shape[:-1] != target.shape[:-1] or raw.shape[-1] != 13 or target.shape[-1] != 12:
        raise ValueError(f"loss shapes: raw {tuple(raw.shape)} must be (..., 13) and target "
                         f"{tuple(target.shape)} (..., 12) over the same steps")
    per_step: dict[str, Any] = {}  # name -> per-step loss tensor
    for name, sl in COMPONENTS:
        fn = relative_l1 if name == "rot" else relative_l2
        per_step[name] = fn(raw[..., sl], target[..., sl], cfg.eps, cfg.relative_to == "both")
    if cfg.w_abs > 0:
        per_step["abs"] = sum(safe_l2(raw[..., sl] - target[..., sl]) if name != "rot"
                              else (raw[..., sl] - target[..., sl]).abs().sum(-1) for name, sl in COMPONENTS)
    per_step["topple"] = F.binary_cross_entropy_with_logits(raw[..., 12], topple.to(raw.dtype), reduction="none")
    if mask is None:
        means = {k: v.mean() for k, v in per_step.items()}
    else:
        w = mask.to(raw.dtype)
        denom = w.sum().clamp_min(1.0)
        means = {k: (v * w).sum() / denom for k, v in per_step.items()}
    total = (cfg.w_vel * means["vel"] + cfg.w_angvel * means["angvel"] + cfg.w_pos * means["pos"]
             + cfg.w_rot * means["rot"] + cfg.w_topple * means["topple"])
    for name in OPTIONAL_TERMS:  # present exactly when their weight is > 0
        if name in means:
            total = total + getattr(cfg, f"w_{name}") * means[name]
    parts = {k: v.detach() for k, v in means.items()}
    parts["total"] = total.detach()
    return total, parts
