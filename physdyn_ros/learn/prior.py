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
"""Coulomb sliding as a per-step prior: the network predicts a residual on top of it (model.prior: sliding,
coupled).

Hybrids of an analytic model and a learned residual beat both pure physics and pure learning on pushing
(Ajay et al. 2018, 2019), and on shapes outside the training families plain Coulomb sliding predicts the
motion better than a network trained without it (physdyn_ros/models/MODEL_CARD.md).
The prior is exact constant-deceleration kinematics over one step of dt, in frame C:
  * horizontal velocity: |v_xy| decreases by mu g per second along its own direction, stopping at zero;
  * spin about z: |w_z| decreases by mu g / r per second (r: RMS horizontal radius of the cloud, the
    friction lever arm over the radius of gyration), stopping at zero;
  * vertical motion and tilt: no prior (zero); the residual predicts them, and toppling.
So a network whose residual is zero (the zero-initialised head) starts as the analytic sliding baseline
(learn/baselines.analytic_sliding; test_prior.py checks that stepping this prior reproduces it).

model.prior coupled: one friction budget for sliding and spinning, the ellipsoidal limit surface of a contact
patch (Goyal et al. 1991; Lynch et al. 1992): with s = |v_xy| and the lever r = (mu g) / (spin deceleration),
the speed decreases by mu g s / |(s, r w_z)| per second and the spin by (spin deceleration) r |w_z| /
|(s, r w_z)|. Pure sliding and pure spinning are unchanged; an object that slides while it turns keeps turning
(the decoupled prior stops the spin of a fast-sliding object within a step, where pybullet's keeps most of
it), and one that spins drifts on.
"""
from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np

import torch
from torch import Tensor

from ..conventions import DT, GRAVITY

#: Smallest lever arm (m) for the spin deceleration: a needle-thin cloud must not stop spinning at once.
MIN_RADIUS = 0.01
#: m/s, regularises |v| at zero (a 1 micron/s error, far below anything measured).
SPEED_EPS = 1e-6


def sliding_step(vel: Tensor, angvel: Tensor, decel: Tensor, spin_decel: Tensor, coupling: Tensor,
                 dt: float = DT) -> Tuple[Tensor, Tensor, Tensor, Tensor]:
    """One step of the prior. vel, angvel (..., 3) physical in C; decel (...,) = mu g (m/s^2); spin_decel
    (...,) = mu g / r (rad/s^2); coupling (...,) 0 (model.prior sliding: the two decelerations independent) or
    1 (coupled: the friction shared over the lever mu g / spin_decel, see the module docstring).
    Returns physical increments d_vel, d_angvel, d_pos, d_rot (..., 3)."""
    vxy = vel[..., :2]
    # + SPEED_EPS^2 under the root: a finite gradient at rest (windows end in rest frames with v = 0 exactly)
    speed = torch.sqrt((vxy * vxy).sum(-1, keepdim=True) + 1e-12)  # 1e-12 = SPEED_EPS ** 2 (TorchScript: a literal)
    wz = angvel[..., 2:3]
    w_abs = wz.abs()
    c = coupling[..., None]
    on = (c > 0).to(c.dtype)
    # friction shared between sliding and spinning (ellipsoidal limit surface, lever r = c mu g / spin_decel):
    # shares speed / |(speed, r w)| and r |w| / |(speed, r w)|; c = 0 leaves both decelerations exactly as they were
    lever_w = c * decel[..., None] / spin_decel[..., None].clamp_min(1e-9) * w_abs
    norm = torch.sqrt(speed * speed + lever_w * lever_w)
    a = decel[..., None] * (1.0 - on + on * speed / norm)
    alpha = spin_decel[..., None] * (1.0 - on + on * lever_w / norm)
    direction = vxy / speed
    t_slide = torch.minimum(speed / a.clamp_min(1e-9), torch.full_like(speed, dt))
    dist = speed * t_slide - 0.5 * a * t_slide * t_slide
    zeros1 = torch.zeros_like(speed)
    d_pos = torch.cat([dist * direction, zeros1], -1)
    # new - old (not a change of speed times the direction): a stopped object's velocity is then exactly 0
    d_vel = torch.cat([torch.clamp(speed - a * dt, min=0.0) * direction - vxy, zeros1], -1)

    sign = torch.sign(wz)
    t_spin = torch.minimum(w_abs / alpha.clamp_min(1e-9), torch.full_like(w_abs, dt))
    d_yaw = sign * (w_abs * t_spin - 0.5 * alpha * t_spin * t_spin)
    d_wz = sign * torch.clamp(w_abs - alpha * dt, min=0.0) - wz
    zeros2 = torch.zeros_like(vxy)
    d_rot = torch.cat([zeros2, d_yaw], -1)
    d_angvel = torch.cat([zeros2, d_wz], -1)
    return d_vel, d_angvel, d_pos, d_rot


def decelerations(cloud_c: Tensor, friction: float) -> Tuple[Tensor, Tensor]:
    """(mu g, mu g / r) per cloud (B, P, 3) in C, centred: r = RMS horizontal distance from the centroid."""
    xy = cloud_c[..., :2] - cloud_c[..., :2].mean(dim=-2, keepdim=True)
    radius = torch.sqrt((xy * xy).sum(-1).mean(-1)).clamp_min(MIN_RADIUS)
    decel = torch.full_like(radius, float(friction) * GRAVITY)
    return decel, decel / radius


def prior_raw(x: Tensor, decel: Tensor, spin_decel: Tensor, coupling: Tensor, scale_in: Tensor, scale_out: Tensor,
              dt: float = DT) -> Tensor:
    """The prior in the network's normalised spaces: inputs x (..., 6) -> outputs (..., 12) (raw columns 0:12)."""
    v = x[..., :3] * scale_in[:3]
    w = x[..., 3:6] * scale_in[3:6]
    d_vel, d_angvel, d_pos, d_rot = sliding_step(v, w, decel, spin_decel, coupling, dt)
    return torch.cat([d_vel, d_angvel, d_pos, d_rot], -1) / scale_out[:12]


def prior_constants(decel: float, spin_decel: float, scale_in: Sequence[float], scale_out: Sequence[float],
                    gain: Sequence[float], dt: float = DT, coupling: float = 0.0) -> tuple:
    """The numbers prior_into needs, gathered once per roll-out: the decelerations (mu g, spin deceleration), the
    input (6,) and output (13,) scales and the feedback gain (6,) of the model, dt and the coupling (0 or 1)."""
    si, so, g = [float(v) for v in scale_in], [float(v) for v in scale_out], [float(v) for v in gain]
    return (float(decel), float(spin_decel), si[0], si[1], si[5], 1 / so[0], 1 / so[1], 1 / so[5], 1 / so[6],
            1 / so[7], 1 / so[11], g[0], g[1], g[5], float(dt), float(coupling))


def prior_into(row: np.ndarray, x: np.ndarray, c: tuple) -> None:
    """prior_raw added in place to one step of the batch-1 kernel: row[:12] (the outputs) and row[13:19] (the
    next input, through the feedback gain); only the six non-zero components, as Python floats."""
    decel, spin, s0, s1, s5, o0, o1, o5, o6, o7, o11, g0, g1, g5, dt, coupling = c
    vx, vy, wz = float(x[0]) * s0, float(x[1]) * s1, float(x[5]) * s5
    speed = math.sqrt(vx * vx + vy * vy + SPEED_EPS * SPEED_EPS)
    if coupling:  # sliding_step's shared friction
        lever_w = coupling * decel / max(spin, 1e-9) * abs(wz)
        norm = math.sqrt(speed * speed + lever_w * lever_w)
        decel, spin = decel * speed / norm, spin * lever_w / norm
    t = min(speed / decel, dt) if decel > 0 else dt
    dist = speed * t - 0.5 * decel * t * t
    new = max(speed - decel * dt, 0.0)
    ux, uy = vx / speed, vy / speed
    p0, p1 = (new * ux - vx) * o0, (new * uy - vy) * o1
    row[0] += p0
    row[1] += p1
    row[6] += dist * ux * o6
    row[7] += dist * uy * o7
    row[13] += g0 * p0
    row[14] += g1 * p1
    if wz != 0.0:
        w_abs, sign = abs(wz), math.copysign(1.0, wz)
        t = min(w_abs / spin, dt) if spin > 0 else dt
        p5 = (sign * max(w_abs - spin * dt, 0.0) - wz) * o5
        row[5] += p5
        row[11] += sign * (w_abs * t - 0.5 * spin * t * t) * o11
        row[18] += g5 * p5
