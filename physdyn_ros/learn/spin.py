"""Spin head: how long will this push keep the object spinning, relative to what the dynamics network predicts?

Why (issue 11, session 15): the roll-outs stop spins too soon on shapes the network was not trained on. Scaling each
step's predicted change of spin about z by one factor k per push (DynamicsModel.rollout_raw's spin_scale) and
picking k by hand on the test answers shows what such a correction is worth (bench/spin_budget.py: on
pybullet_data one k for all pushes, best 0.71, reads 5.29° against 5.62°, one per shape 4.19°, one per push 1.31°).
The dynamics loss hardly sees that direction (session 14: the model sits at its loss's optimum, 1.13x the data's
mean spin deceleration), so this head learns it directly: from the shape feature and the initial twist it predicts
log k, fitted (learn/spin_fit.py, `physdyn fit-spin`) to minimise each training push's final error read off that
push's own error curve over k. Measured (model card, session 15): it cuts the generated world's rotation p90 by
16-23 % and makes pybullet_data's median worse, so the shipped model has none.
It runs after the dynamics network is frozen, like the topple head; k = 1 (its zero-initialised output) leaves
every roll-out as it was.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np
import torch
from torch import Tensor, nn

#: The factor's range (log-spaced grid of the fit; the head's output is clipped to it).
K_MIN, K_MAX = 0.25, 2.0
#: Twist quantities per push, after the shape feature: |v_xy|, v_z, |w_z|, |w_xy|, and the logs of the three rates.
TWIST_DIMS = 7
_LOG_EPS = 0.01


def twist_quantities(vel: np.ndarray, angvel: np.ndarray) -> np.ndarray:
    """(B, TWIST_DIMS) from the initial twist (B, 3) each, in frame C: invariant to the spin's sense and heading."""
    vel, angvel = np.asarray(vel, np.float64), np.asarray(angvel, np.float64)
    speed, spin = np.linalg.norm(vel[:, :2], axis=1), np.abs(angvel[:, 2])
    tilt = np.linalg.norm(angvel[:, :2], axis=1)
    return np.stack([speed, vel[:, 2], spin, tilt, np.log(speed + _LOG_EPS), np.log(spin + _LOG_EPS),
                     np.log(tilt + _LOG_EPS)], axis=1)


class SpinHead(nn.Module):
    """MLP [shape feature, twist quantities] (standardised) -> log k, clipped to [log K_MIN, log K_MAX]."""

    mean: Tensor
    std: Tensor

    def __init__(self, feature_dim: int, hidden: int = 64) -> None:
        super().__init__()
        self.feature_dim = int(feature_dim)
        self.in_dim = self.feature_dim + TWIST_DIMS
        self.net = nn.Sequential(nn.Linear(self.in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, 1))
        self.register_buffer("mean", torch.zeros(self.in_dim))
        self.register_buffer("std", torch.ones(self.in_dim))
        self.reset_output()
        self._np: Optional[dict[str, Any]] = None
        self._np_key: Optional[tuple] = None

    def reset_output(self) -> None:
        """k = 1 for every push: the roll-outs as without the head."""
        last = self.net[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def raw_inputs(self, feature: np.ndarray, vel: np.ndarray, angvel: np.ndarray) -> np.ndarray:
        """(B, in_dim) float32 unstandardised inputs."""
        return np.concatenate([np.asarray(feature, np.float64), twist_quantities(vel, angvel)], 1).astype(np.float32)

    def log_factor(self, x: Tensor) -> Tensor:
        """(B,) log k of raw inputs x (B, in_dim), standardised here (differentiable: the fit)."""
        return self.net((x - self.mean) / self.std)[:, 0].clamp(float(np.log(K_MIN)), float(np.log(K_MAX)))

    def forward(self, feature: Tensor, vel: Tensor, angvel: Tensor) -> Tensor:
        """(B,) factor k for feature (B, F) and the initial twist vel / angvel (B, 3) in frame C."""
        x = torch.from_numpy(self.raw_inputs(feature.detach().cpu().numpy(), vel.detach().cpu().numpy(),
                                             angvel.detach().cpu().numpy())).to(feature)
        return torch.exp(self.log_factor(x))

    def _numpy(self) -> dict[str, Any]:
        """The weights as float64 numpy arrays, rebuilt when a parameter or buffer changes (the batch-1 path)."""
        tensors = list(self.parameters()) + list(self.buffers())
        key = tuple((t.data_ptr(), t._version) for t in tensors)
        if self._np is None or self._np_key != key:
            layers = [m for m in self.net if isinstance(m, nn.Linear)]
            self._np = {"w": [m.weight.detach().double().cpu().numpy().T for m in layers],
                        "b": [m.bias.detach().double().cpu().numpy() for m in layers],
                        "mean": self.mean.double().cpu().numpy(), "std": self.std.double().cpu().numpy()}
            self._np_key = key
        return self._np

    def factor(self, feature: np.ndarray, vel: np.ndarray, angvel: np.ndarray) -> np.ndarray:
        """forward in numpy (float64): (B,) k."""
        w = self._numpy()
        h = (self.raw_inputs(feature, vel, angvel).astype(np.float64) - w["mean"]) / w["std"]
        for i, (a, b) in enumerate(zip(w["w"], w["b"])):
            h = h @ a + b
            if i < len(w["w"]) - 1:
                h = np.maximum(h, 0.0)
        return np.exp(np.clip(h[:, 0], np.log(K_MIN), np.log(K_MAX)))

    def _apply(self, fn, recurse: bool = True) -> "SpinHead":
        self._np = None  # .to() / .double() replace the tensors: rebuild the numpy copy
        return super()._apply(fn, recurse)
