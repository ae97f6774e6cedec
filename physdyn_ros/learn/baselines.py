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
"""Non-learned baselines for `physdyn evaluate`, on the same sequences as the model.

* analytic sliding: the object stays upright on the plane; Coulomb friction decelerates the horizontal COM
  velocity by mu * g (exact constant-deceleration kinematics, stopping at 0), spin about z decays linearly
  with angular deceleration mu * g / r (r = RMS horizontal radius of the cloud: friction acting at the mean
  contact radius on a body whose radius of gyration is about r), and tilt rates are dropped (no wobble).
  Uses the simulation's true friction, so it is an optimistic physics-only baseline.
* pybullet re-simulation: the convex hull of the object's cloud, the true initial state, and a friction
  coefficient off by a relative error (+-20 % by default): "an engine with estimated parameters", the
  honest baseline for a learned model (docs: peers-and-anchors). pybullet is imported lazily, only here.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np

from .. import geometry as geo
from ..conventions import GRAVITY


def analytic_sliding(pos0: np.ndarray, quat0: np.ndarray, vel0: np.ndarray, angvel0: np.ndarray,
                     friction: np.ndarray, radius: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
    """Batched closed-form roll-out. Inputs (B, 3) / (B, 4) / (B,) world frame; outputs (B, H+1, *) arrays
    pos, quat, lin_vel, ang_vel."""
    pos0, vel0, angvel0 = (np.asarray(a, dtype=np.float64) for a in (pos0, vel0, angvel0))
    mu = np.asarray(friction, dtype=np.float64)
    t = np.arange(horizon + 1) * dt  # (H+1,)
    a_lin = (mu * GRAVITY)[:, None]  # (B, 1)
    v_h = vel0[:, :2]
    speed0 = np.linalg.norm(v_h, axis=-1, keepdims=True)  # (B, 1)
    direction = np.divide(v_h, speed0, out=np.zeros_like(v_h), where=speed0 > 0)
    t_stop = speed0 / np.maximum(a_lin, 1e-12)
    tc = np.minimum(t[None, :], t_stop)  # time spent sliding
    speed = np.maximum(speed0 - a_lin * t[None, :], 0.0)  # (B, H+1)
    dist = speed0 * tc - 0.5 * a_lin * tc ** 2
    pos = np.repeat(pos0[:, None, :], horizon + 1, axis=1)
    pos[..., :2] += dist[..., None] * direction[:, None, :]
    lin_vel = np.zeros_like(pos)
    lin_vel[..., :2] = speed[..., None] * direction[:, None, :]

    a_ang = (mu * GRAVITY / np.maximum(np.asarray(radius, dtype=np.float64), 1e-3))[:, None]
    wz0 = angvel0[:, 2:3]
    w_abs = np.abs(wz0)
    tw = np.minimum(t[None, :], w_abs / np.maximum(a_ang, 1e-12))
    yaw = np.sign(wz0) * (w_abs * tw - 0.5 * a_ang * tw ** 2)  # (B, H+1)
    ang_vel = np.zeros_like(pos)
    ang_vel[..., 2] = np.sign(wz0) * np.maximum(w_abs - a_ang * t[None, :], 0.0)
    ang_vel[:, 0] = angvel0  # frame 0 is the given state
    lin_vel[:, 0] = vel0
    quat = geo.quat_multiply(geo.yaw_quat(yaw), geo.quat_normalize(quat0)[:, None, :])
    return {"pos": pos, "quat": quat, "lin_vel": lin_vel, "ang_vel": ang_vel}


def horizontal_radius(points_world_axes: np.ndarray) -> np.ndarray:
    """RMS horizontal distance of cloud points (B, N, 3) from their centroid: the spin-friction lever arm."""
    p = np.asarray(points_world_axes, dtype=np.float64)
    d = p[..., :2] - p[..., :2].mean(axis=-2, keepdims=True)
    return np.sqrt(np.mean(np.sum(d * d, axis=-1), axis=-1))


def sim_config_from_manifest(manifest: dict[str, Any]) -> Any:
    """The generator's physics settings (SimConfig) with collision forced to the convex hull."""
    from dataclasses import fields, replace

    from ..sim import SimConfig

    gen = manifest.get("generator", {}) if isinstance(manifest, dict) else {}
    raw = gen.get("sim", gen.get("sim_config", {})) if isinstance(gen, dict) else {}
    known = {f.name for f in fields(SimConfig)}
    cfg = SimConfig(**{k: v for k, v in dict(raw or {}).items() if k in known})
    return replace(cfg, collision="hull")


def pybullet_resimulate(points_obj: np.ndarray, scale: np.ndarray, pos0: np.ndarray, quat0: np.ndarray,
                        vel0: np.ndarray, angvel0: np.ndarray, friction: np.ndarray, horizon: int,
                        manifest: Optional[dict[str, Any]] = None) -> dict[str, np.ndarray]:
    """Re-simulate each sequence from its true initial state with the convex hull of its canonical cloud.

    points_obj (B, N, 3) object frame (origin at the COM), scale (B, 3), states (B, *) world, friction (B,)
    already perturbed by the caller. Returns (B, H+1, *) arrays pos, quat, lin_vel, ang_vel, toppled.
    """
    from ..sim import Simulator, simulate_from_state  # pybullet: only the physics baseline needs it

    config = sim_config_from_manifest(manifest or {})
    keys = ("pos", "quat", "lin_vel", "ang_vel", "toppled")
    out: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    with Simulator(config) as sim:
        for i in range(len(points_obj)):
            rec = simulate_from_state(points_obj[i], scale[i], pos0[i], quat0[i], vel0[i], angvel0[i],
                                      friction=float(friction[i]), num_frames=horizon + 1, config=config, sim=sim)
            for k in keys:
                out[k].append(np.asarray(rec[k]))
            sim.remove()
    return {k: np.stack(v) for k, v in out.items()}
