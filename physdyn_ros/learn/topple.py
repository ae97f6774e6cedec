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
"""Whole-push topple head: will this push topple the object at some point of its motion?

Why a separate head: the LSTM's per-step topple logit is trained on 15-frame windows and decides from the
recurrent state, which generalises poorly to unseen shape families. Whether a push topples is mostly rigid-body
statics and energy: the height of the centre of mass over the support polygon, how far that polygon reaches in the
direction of the push (friction at the base tips the object forward while it slides), and the kinetic energy
against the potential barrier of tipping over that edge. This head sees those quantities, computed from the
object's cloud (learn/support.py), next to the learned shape feature and the initial twist, and predicts one
calibrated probability per push. The per-step probabilities
of a roll-out keep the LSTM's timing, scaled so that their maximum is this probability (rules.whole_push_topple).

The descriptors are numpy (learn/support.py), the head a small ensemble of MLPs (averaging out the fit's
seed-to-seed spread) whose input standardisation is stored with it. It is fitted after the dynamics network,
on its frozen features (learn/topple_fit.py, `physdyn fit-topple`), on whole simulations, full and partial
clouds.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch
from scipy.special import expit
from torch import Tensor, nn

from .support import DESCRIPTOR_DIM, PUSH_DIM, push_quantities

#: Novelty 1 is the training inputs' distance at this quantile (flags inputs far from the training data).
NOVELTY_QUANTILE = 0.995
RANGE_MARGIN = 1.05


def apply_calibration(prob: np.ndarray, scale: float, shift: float) -> np.ndarray:
    """Probabilities (B,) through a (scale, shift) calibration of their logit (ToppleHead.calibration); the
    identity returns them unchanged, bit for bit."""
    if scale == 1.0 and shift == 0.0:
        return prob
    p = np.clip(prob, 1e-7, 1.0 - 1e-7)
    return expit(scale * np.log(p / (1.0 - p)) + shift)


def _squash(x: Tensor) -> Tensor:
    """Signed log: physical inputs span orders of magnitude (mm-scale reaches, 10 m/s pushes)."""
    return torch.sign(x) * torch.log1p(10.0 * x.abs())


class ToppleHead(nn.Module):
    """Ensemble of small MLPs: [shape feature, squashed descriptors, squashed push quantities] -> probability."""

    mean: Tensor
    std: Tensor
    precision: Tensor
    novelty_scale: Tensor
    range_centre: Tensor
    range_radius: Tensor
    calibration: Tensor

    def __init__(self, feature_dim: int, hidden: int = 64, members: int = 5) -> None:
        super().__init__()
        self.feature_dim = int(feature_dim)
        self.desc_dim, self.push_dim = DESCRIPTOR_DIM, PUSH_DIM
        self.in_dim = self.feature_dim + self.desc_dim + self.push_dim
        self.members = nn.ModuleList([
            nn.Sequential(nn.Linear(self.in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                          nn.Linear(hidden, 1)) for _ in range(int(members))])
        self.register_buffer("mean", torch.zeros(self.in_dim))
        self.register_buffer("std", torch.ones(self.in_dim))
        # novelty (set_novelty): the larger of (a) the Mahalanobis distance of the standardised input under the
        # training inputs' covariance (its precision matrix), in units of the training inputs' 99.5th percentile
        # distance: an unusual combination; (b) how far any one input lies outside the training inputs' range
        # (centre +- radius, 5 % wider than min..max): a speed, a vertical velocity or a size never trained on
        self.register_buffer("precision", torch.eye(self.in_dim))
        self.register_buffer("novelty_scale", torch.ones(()))
        self.register_buffer("range_centre", torch.zeros(self.in_dim))
        self.register_buffer("range_radius", torch.full((self.in_dim,), float("inf")))
        # (scale, shift) on the logit of the members' mean probability, fitted on families the members were not
        # trained on (topple_fit.cross_validate): the ensemble is calibrated for the shapes of its training
        # families and under-confident on new ones; identity for heads fitted without it
        self.register_buffer("calibration", torch.tensor([1.0, 0.0]))
        self._np: Optional[dict[str, np.ndarray]] = None
        self._np_tensors: Optional[list[Tensor]] = None
        self._np_key: Optional[tuple] = None

    def raw_inputs(self, feature: Tensor, desc: Tensor, push: Tensor) -> Tensor:
        """(B, in_dim) unstandardised inputs of feature (B, F), desc (B, DESCRIPTOR_DIM), push (B, PUSH_DIM)."""
        return torch.cat([feature, _squash(desc), _squash(push)], dim=-1)

    def member_logits(self, x: Tensor) -> Tensor:
        """(members, B) logits of raw inputs x (B, in_dim), standardised here."""
        z = (x - self.mean) / self.std
        return torch.stack([m(z)[:, 0] for m in self.members])

    def set_novelty(self, x: Tensor, quantile: float = NOVELTY_QUANTILE) -> None:
        """Fit the novelty statistics on the training inputs x (B, in_dim) (raw; mean / std already set)."""
        z = (x - self.mean) / self.std
        # shrunk towards the identity (the inputs are standardised): a stable inverse with few samples
        cov = 0.9 * torch.cov(z.T.double()) + 0.1 * torch.eye(self.in_dim, dtype=torch.float64)
        self.precision.copy_(torch.linalg.inv(cov).float())
        self.novelty_scale.copy_(torch.quantile(self._distance(z).double(), quantile).float())
        lo, hi = x.min(dim=0).values, x.max(dim=0).values
        # a push without tilting spin, or an object at rest, is ordinary even where every training push had
        # some: the per-push quantities' ranges reach zero
        push = slice(self.in_dim - self.push_dim, self.in_dim)
        lo[push], hi[push] = lo[push].clamp_max(0.0), hi[push].clamp_min(0.0)
        self.range_centre.copy_(0.5 * (lo + hi))
        self.range_radius.copy_((0.5 * RANGE_MARGIN * (hi - lo)).clamp_min(1e-6))

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args: Any, **kwargs: Any) -> None:
        # checkpoints written before the calibration existed load with the identity
        state_dict.setdefault(prefix + "calibration", torch.tensor([1.0, 0.0]))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _distance(self, z: Tensor) -> Tensor:
        return torch.einsum("bi,ij,bj->b", z, self.precision, z).clamp_min(0.0).sqrt()

    def novelty(self, x: Tensor) -> Tensor:
        """(B,) how far raw inputs x (B, in_dim) lie from the training inputs: > 1 beyond NOVELTY_QUANTILE of
        their Mahalanobis distances or outside their range (a shape or push unlike those the model was fitted on)."""
        combined = self._distance((x - self.mean) / self.std) / self.novelty_scale
        outside = ((x - self.range_centre).abs() / self.range_radius).max(dim=-1).values
        return torch.maximum(combined, outside)

    def forward(self, feature: Tensor, desc: Tensor, push: Tensor) -> Tensor:
        """(B,) probability that the push topples the object."""
        return self.calibrated(torch.sigmoid(self.member_logits(self.raw_inputs(feature, desc, push))).mean(dim=0))

    def calibrated(self, mean_prob: Tensor) -> Tensor:
        """The calibration applied to the members' mean probability (B,)."""
        if bool(self.calibration[0] == 1.0) and bool(self.calibration[1] == 0.0):
            return mean_prob
        p = mean_prob.clamp(1e-7, 1.0 - 1e-7)
        return torch.sigmoid(self.calibration[0] * torch.logit(p) + self.calibration[1])

    def _apply(self, fn: Any, recurse: bool = True) -> "ToppleHead":
        self._np_tensors, self._np = None, None  # .to() / .double() replace the buffers: rebuild the copy
        return super()._apply(fn, recurse)

    def _numpy(self) -> dict[str, np.ndarray]:
        """The weights as stacked numpy arrays, rebuilt when a parameter or buffer changes (inference runs in
        numpy: at batch 1 torch's per-call overhead costs more than the arithmetic, bench/bench_predictor.py)."""
        if self._np_tensors is None:  # the tensors listed once: walking the module tree costs on every call
            self._np_tensors = list(self.parameters()) + list(self.buffers())
        key = tuple((t.data_ptr(), t._version) for t in self._np_tensors)
        if self._np is None or self._np_key != key:
            def stack(layer: int, what: str) -> np.ndarray:
                return torch.stack([getattr(list(m.children())[layer], what).detach()
                                    for m in self.members]).double().cpu().numpy()

            w1 = stack(0, "weight")  # (M, H, in)
            self._np = {"w1": np.ascontiguousarray(w1.transpose(2, 0, 1).reshape(self.in_dim, -1)),
                        "b1": stack(0, "bias").reshape(-1), "w2": np.ascontiguousarray(stack(2, "weight")
                                                                                     .transpose(0, 2, 1)),
                        "b2": stack(2, "bias"), "w3": stack(4, "weight")[:, 0], "b3": stack(4, "bias")[:, 0],
                        "mean": self.mean.double().cpu().numpy(), "std": self.std.double().cpu().numpy(),
                        "precision": self.precision.double().cpu().numpy(),
                        "scale": self.novelty_scale.double().cpu().numpy(),
                        "centre": self.range_centre.double().cpu().numpy(),
                        "radius": self.range_radius.double().cpu().numpy(),
                        "calibration": self.calibration.double().cpu().numpy()}
            self._np_key = key
        return self._np

    def assess(self, feature: np.ndarray, desc: np.ndarray, vel: np.ndarray,
               angvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(probability (B,), novelty (B,)) of feature (B, F), desc (B, D), vel / angvel (B, 3) in frame C: the
        forward pass and novelty above, in numpy (float64)."""
        w = self._numpy()
        if np.ndim(desc) != 2 or np.shape(desc)[1] != self.desc_dim:
            raise ValueError(f"the topple head needs (B, {self.desc_dim}) support descriptors, got {np.shape(desc)}")
        push = push_quantities(desc, vel, angvel)
        squashed = np.concatenate([np.asarray(desc), push], axis=1)
        squashed = np.sign(squashed) * np.log1p(10.0 * np.abs(squashed))
        x = np.concatenate([np.asarray(feature, dtype=np.float64), squashed], axis=1)
        z = (x - w["mean"]) / w["std"]
        members = len(w["b3"])
        h1 = np.maximum(z @ w["w1"] + w["b1"], 0.0).reshape(len(z), members, -1)  # (B, M, H)
        # the members' products through BLAS (numpy's einsum has no BLAS path for these: 10x slower at 1024 rows)
        h2 = np.maximum(np.matmul(h1.transpose(1, 0, 2), w["w2"]).transpose(1, 0, 2) + w["b2"], 0.0)
        logits = np.einsum("bmj,mj->bm", h2, w["w3"]) + w["b3"]
        prob = apply_calibration(np.mean(expit(logits), axis=1), *w["calibration"])  # expit: no overflow warning
        combined = np.sqrt(np.maximum(np.sum((z @ w["precision"]) * z, axis=1), 0.0)) / w["scale"]
        novelty = np.maximum(combined, np.max(np.abs(x - w["centre"]) / w["radius"], axis=1))
        return prob, novelty
