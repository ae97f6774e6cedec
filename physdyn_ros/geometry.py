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
"""Rotation helpers (thin wrappers over scipy.spatial.transform.Rotation) and the yaw-equivariant heading of a
point cloud, topple labels and the up-axis tilt (specific to this project, numpy).

Conventions (see conventions.py): quaternions are (x, y, z, w) (scipy's order), unit norm, and map object ->
world; an axis-angle vector is axis * angle (rad). Every function broadcasts over leading dimensions and computes
in float64, so chains of rotations stay accurate in float32 data.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .conventions import TOPPLE_ANGLE

__all__ = [
    "quat_normalize", "quat_multiply", "quat_conjugate", "quat_inverse", "quat_rotate", "quat_to_matrix",
    "matrix_to_quat", "axis_angle_to_quat", "quat_to_axis_angle", "quat_angle_between", "quat_compose_scan",
    "axis_angle_to_matrix", "matrix_compose_scan",
    "yaw_matrix", "yaw_quat", "rotate_yaw", "canonical_heading", "topple_labels", "up_tilt_angle",
]


def _f64(x: np.ndarray | list | tuple | float) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _rot(q: np.ndarray | list | tuple) -> Rotation:
    """scipy Rotation(s) of quaternions (..., 4) (x, y, z, w: scipy's order); normalises, keeps the sign."""
    return Rotation.from_quat(_f64(q))


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s); raises ValueError on a zero or non-finite quaternion."""
    q = _f64(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n < 1e-12):
        raise ValueError("quaternion must be finite and non-zero")
    return q / n


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b first, then a) of unit quaternions (inputs are normalised); broadcasts."""
    return (_rot(a) * _rot(b)).as_quat()


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """(-x, -y, -z, w): the inverse rotation of a unit quaternion, without normalising (any quaternion)."""
    q = _f64(q)
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def quat_inverse(q: np.ndarray) -> np.ndarray:
    """Inverse rotations (unit quaternions) of (not necessarily unit) quaternions."""
    return _rot(q).inv().as_quat()


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4); broadcasts."""
    return _rot(q).apply(_f64(v))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (normalised first)."""
    return _rot(q).as_matrix()


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) of rotation matrices (..., 3, 3)."""
    return Rotation.from_matrix(_f64(m)).as_quat(canonical=True)


def axis_angle_to_quat(rv: np.ndarray) -> np.ndarray:
    """Exponential map: rotation vectors (..., 3) (axis * angle, rad) -> unit quaternions (w < 0 beyond pi)."""
    return Rotation.from_rotvec(_f64(rv)).as_quat()


def quat_to_axis_angle(q: np.ndarray) -> np.ndarray:
    """Logarithm map: quaternions -> rotation vectors with angle in [0, pi] (shortest rotation)."""
    return _rot(q).as_rotvec()


def quat_angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad, in [0, pi]) between orientations a and b (q and -q are the same orientation)."""
    return (_rot(a) * _rot(b).inv()).magnitude()


def axis_angle_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (..., 3) -> rotation matrices (..., 3, 3)."""
    return Rotation.from_rotvec(_f64(rv)).as_matrix()


def matrix_compose_scan(deltas: np.ndarray, r0: np.ndarray) -> np.ndarray:
    """Rotations after world-fixed increments: R_0 = r0, R_{t+1} = deltas[t] @ R_t.

    deltas: (..., H, 3, 3), r0: (..., 3, 3) -> (..., H+1, 3, 3). A parallel prefix scan: log2(H) batched
    matrix products instead of H sequential ones (a 60-step roll-out composes in ~0.1 ms). scipy has no scan;
    batched matrix products are what numpy does best.
    """
    d = _f64(deltas)
    acc = np.concatenate([np.broadcast_to(_f64(r0)[..., None, :, :], d.shape[:-3] + (1, 3, 3)), d], axis=-3)
    n, k = acc.shape[-3], 1
    while k < n:
        # later factors on the left keep the time order: acc[i] <- acc[i] @ acc[i - k]
        acc = np.concatenate([acc[..., :k, :, :], acc[..., k:, :, :] @ acc[..., :-k, :, :]], axis=-3)
        k *= 2
    return acc


def quat_compose_scan(deltas: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Quaternion version of matrix_compose_scan: q_0 = q0, q_{t+1} = deltas[t] * q_t; (..., H+1, 4), w >= 0."""
    return matrix_to_quat(matrix_compose_scan(quat_to_matrix(quat_normalize(deltas)),
                                              quat_to_matrix(quat_normalize(q0))))


def _about_z(psi: np.ndarray | float) -> Rotation:
    psi = _f64(psi)
    return Rotation.from_rotvec(psi[..., None] * np.array([0.0, 0.0, 1.0]))


def yaw_matrix(psi: np.ndarray | float) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about +z by psi (rad)."""
    return _about_z(psi).as_matrix()


def yaw_quat(psi: np.ndarray | float) -> np.ndarray:
    """Quaternions (..., 4) of a rotation about +z by psi (rad): (0, 0, sin(psi/2), cos(psi/2))."""
    return _about_z(psi).as_quat()


def rotate_yaw(v: np.ndarray, psi: np.ndarray | float) -> np.ndarray:
    """Rotate vectors (..., 3) about +z by psi; psi broadcasts against v[..., 0].

    Plain numpy on purpose: a planar rotation of many vectors (whole datasets, the planner's batches) by per-element
    headings; scipy would build one Rotation per element first (the result is the same: yaw_matrix(psi) @ v).
    """
    v, psi = _f64(v), _f64(psi)
    c, s = np.cos(psi), np.sin(psi)
    x, y = v[..., 0], v[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, np.broadcast_to(v[..., 2], np.broadcast(x, c).shape)], -1)


def topple_labels(quat: np.ndarray, angle: float = TOPPLE_ANGLE) -> tuple[np.ndarray, int]:
    """Per-frame toppled flags (T,) of an orientation sequence (T, 4) and the first toppled frame (-1: none).

    A frame counts once the up axis tilts more than `angle`; from then on the object stays toppled.
    """
    q = _f64(quat)
    over = up_tilt_angle(q / np.linalg.norm(q, axis=-1, keepdims=True)) > angle
    first = int(np.argmax(over)) if over.any() else -1
    toppled = np.zeros(len(over), dtype=bool)
    if first >= 0:
        toppled[first:] = True
    return toppled, first


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Yaw (rad) of the x axis projected on the table, for (..., 4) quaternions (x, y, z, w)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def up_tilt_angle(q: np.ndarray) -> np.ndarray:
    """Angle (rad) between the object's up axis (object z) and world up, for orientations q."""
    q = _f64(q)
    x, y = q[..., 0], q[..., 1]
    up_z = 1.0 - 2.0 * (x * x + y * y)  # z component of R e_z
    return np.arccos(np.clip(up_z, -1.0, 1.0))


def canonical_heading(cloud: np.ndarray, tol: float = 0.1) -> np.ndarray | float:
    """Yaw (rad, in [-pi, pi)) of a canonical horizontal axis of a cloud given in world-aligned axes.

    Exactly equivariant: rotating the cloud by psi about z (and translating it) adds psi to the result (for a
    cloud with a k-fold symmetry, up to that symmetry). With z_i = x_i + i y_i of the centred points, each
    complex moment c_k picks up a phase e^{i k psi} under the rotation, so arg(c_k) / k moves with psi,
    modulo 2 pi / k; the k candidate directions are told apart by the third moment of the points along them,
    which also rotates with the cloud.

    1. anisotropic horizontal spread (c_2 = mean z^2 clearly non-zero): the principal (major) axis, pointing
       to the side with the positive third moment (the skewness sign rule).
    2. near-isotropic (square, triangle, n-gon or round cross sections): the strongest of c_1 = mean(|z|^2 z),
       c_3, ..., c_6 (strength normalised to [0, 1]), its k candidates resolved the same way.
    Deterministic throughout; only exact ties (a perfectly symmetric cloud) fall to the first candidate.
    The threshold on c_2 is max(tol, 3 / sqrt(N)): above the sampling noise of N points.

    cloud: (..., N, 3). Returns a float for a single cloud, an array (...) for a batch. Raises ValueError on
    an empty, wrongly shaped or non-finite cloud.
    """
    pts = _f64(cloud)
    if pts.ndim < 2 or pts.shape[-1] != 3:
        raise ValueError(f"cloud must have shape (..., N, 3), got {pts.shape}")
    n = pts.shape[-2]
    if n == 0:
        raise ValueError("cloud is empty")
    if not np.all(np.isfinite(pts)):
        raise ValueError("cloud contains non-finite values")
    c = pts[..., :2] - pts[..., :2].mean(axis=-2, keepdims=True)
    z = c[..., 0] + 1j * c[..., 1]  # (..., N)
    r2 = z.real ** 2 + z.imag ** 2
    zn = z / np.sqrt(np.maximum(r2.mean(axis=-1), 1e-300))[..., None]
    r2 = r2 / np.maximum(r2.mean(axis=-1, keepdims=True), 1e-300)  # |zn|^2
    # moments c_k = mean zn^k (k = 2..6) and c_1 = mean |zn|^2 zn, by repeated products (no complex pow)
    zk = zn
    moments: dict[int, np.ndarray] = {1: np.mean(r2 * zn, axis=-1)}
    power = {1: 3}
    for k in range(2, 7):
        zk = zk * zn
        moments[k] = zk.mean(axis=-1)
        power[k] = k
    rk = {1: np.ones_like(r2)}
    for k in range(2, 7):
        rk[k] = rk[k - 1] * r2

    def strength(k: int) -> np.ndarray:
        """|c_k| / sqrt(mean |z|^{2p}) in [0, 1] (Cauchy-Schwarz)."""
        return np.abs(moments[k]) / np.sqrt(np.maximum(rk[power[k]].mean(axis=-1), 1e-300))

    s2 = strength(2)
    order = np.where(s2 > max(tol, 3.0 / np.sqrt(n)), 2, 0)
    phase = np.where(order == 2, np.angle(moments[2]), 0.0)
    best = np.full(s2.shape, -1.0)
    for k in (1, 3, 4, 5, 6):
        sk = strength(k)
        take = (order != 2) & (sk > best)
        order = np.where(take, k, order)
        phase = np.where(take, np.angle(moments[k]), phase)
        best = np.where(take, sk, best)
    # k candidate directions (mod 2 pi / k); choose the one with the largest third moment along it:
    # with u = Re(zn e^{-i t}), mean u^3 = 3/4 Re(c_1 e^{-i t}) + 1/4 Re(c_3 e^{-3 i t})
    j = np.arange(6)
    cand = (phase / order)[..., None] + 2.0 * np.pi * j / order[..., None]  # (..., 6)
    third = (0.75 * np.real(moments[1][..., None] * np.exp(-1j * cand))
             + 0.25 * np.real(moments[3][..., None] * np.exp(-3j * cand)))
    score = np.where(j < order[..., None], third, -np.inf)
    theta = np.take_along_axis(cand, np.argmax(score, axis=-1)[..., None], -1)[..., 0]
    theta = np.mod(theta + np.pi, 2 * np.pi) - np.pi
    return float(theta) if theta.ndim == 0 else theta
