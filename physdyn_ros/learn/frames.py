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
"""The learning frame C (docs/architecture.md, "Learning frame"): numpy only.

Frame C of a roll-out: origin at the initial centre of mass projected on the plane, axes rotated about world z
by the heading of the object's cloud posed at the roll-out start (geometry.canonical_heading). Everything the
network sees or predicts is expressed in C, so the model is exactly equivariant to yaw and horizontal
translation: rotating/translating the scene only changes the frame, never the network's input.

Rotation increments are WORLD-FIXED (spatial): R_{t+1} = Exp(dtheta_t) R_t, with dtheta_t expressed in C.
The network never sees the object's own axes (only the posed cloud), so a body-frame increment (the original
code's choice) would not be a function of its inputs; a spatial increment is, and it is ~ omega_t * dt.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import geometry as geo


@dataclass(frozen=True)
class CanonicalCloud:
    """A cloud expressed in frame C (centred at its own centroid) plus the frame's placement."""

    points: np.ndarray  # (..., N, 3) m, frame C axes, centred at the cloud centroid
    heading: np.ndarray | float  # (...) rad, yaw of C's x axis in the world
    centroid: np.ndarray  # (..., 3) m, world


def pose_cloud(points_obj: np.ndarray, scale: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Canonical object-frame points (..., N, 3), per-axis scale (..., 3), orientation (..., 4) -> world axes.

    The result is centred where the object frame is (the centre of mass), in world-aligned axes: the cloud
    the perception node would see, minus the translation.
    """
    pts = np.asarray(points_obj, dtype=np.float64) * np.asarray(scale, dtype=np.float64)[..., None, :]
    rot = geo.quat_to_matrix(np.asarray(quat, dtype=np.float64))
    return np.matmul(pts, np.swapaxes(rot, -1, -2))


def canonicalize_cloud(cloud_world: np.ndarray, keep: np.ndarray | None = None) -> CanonicalCloud:
    """World-axes cloud (..., N, 3) -> the same cloud in frame C, centred at its centroid.

    Heading and centroid always use all N points; `keep` (..., P) optionally selects the points returned
    (a subsample for the network). Centring at the centroid of the points (not the true centre of mass)
    keeps training and deployment the same: a sensor only ever gives the points.
    """
    cloud = np.asarray(cloud_world, dtype=np.float64)
    heading = geo.canonical_heading(cloud)
    centroid = cloud.mean(axis=-2)
    if keep is not None:
        cloud = np.take_along_axis(cloud, np.asarray(keep)[..., None], axis=-2)
    local = geo.rotate_yaw(cloud - centroid[..., None, :], -np.asarray(heading)[..., None])
    return CanonicalCloud(points=local, heading=heading, centroid=centroid)


def world_to_c(vec: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
    """Rotate free vectors (velocities, increments, axis-angle vectors) from world axes into C.

    heading broadcasts against vec[..., 0], e.g. vec (B, T, 3) with heading[:, None].
    """
    return geo.rotate_yaw(vec, -np.asarray(heading, dtype=np.float64))


def c_to_world(vec: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
    """Rotate free vectors from C back into world axes (inverse of world_to_c)."""
    return geo.rotate_yaw(vec, np.asarray(heading, dtype=np.float64))


def world_increments(pos: np.ndarray, quat: np.ndarray, lin_vel: np.ndarray,
                     ang_vel: np.ndarray) -> dict[str, np.ndarray]:
    """Per-transition changes of state (..., T-1, 3) in world axes, from states (..., T, *).

    d_rot is the world-fixed rotation vector log(q_{t+1} q_t^-1).
    """
    quat = np.asarray(quat, dtype=np.float64)
    dq = geo.quat_multiply(quat[..., 1:, :], geo.quat_conjugate(quat[..., :-1, :]))
    return {
        "d_vel": np.diff(np.asarray(lin_vel, dtype=np.float64), axis=-2),
        "d_angvel": np.diff(np.asarray(ang_vel, dtype=np.float64), axis=-2),
        "d_pos": np.diff(np.asarray(pos, dtype=np.float64), axis=-2),
        "d_rot": geo.quat_to_axis_angle(dq),
    }


def integrate_in_world(heading: float | np.ndarray, position0: np.ndarray, orientation0: np.ndarray,
                       d_pos_c: np.ndarray, d_rot_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted increments in C (..., H, 3) -> world positions (..., H+1, 3) and orientations (..., H+1, 4).

    position0 (..., 3) and orientation0 (..., 4) are the world state at the roll-out start.
    """
    h = np.asarray(heading, dtype=np.float64)[..., None]
    dp = c_to_world(d_pos_c, h)
    p0 = np.asarray(position0, dtype=np.float64)[..., None, :]
    positions = np.concatenate([p0, p0 + np.cumsum(dp, axis=-2)], axis=-2)
    rot = geo.matrix_compose_scan(geo.axis_angle_to_matrix(c_to_world(d_rot_c, h)),
                                  geo.quat_to_matrix(geo.quat_normalize(orientation0)))
    orientations = geo.matrix_to_quat(rot)
    return positions, orientations


def _exp_map(rv: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3): scipy's Rotation.from_rotvec(rv).as_quat(), in numpy
    for compose_rotations' hot path (see there)."""
    rv = np.asarray(rv, dtype=np.float64)
    a = np.sqrt(np.sum(rv * rv, axis=-1, keepdims=True))
    # sin(a/2)/a with its Taylor series near 0 (no division by zero for the identity)
    k = np.where(a > 1e-6, np.sin(0.5 * a) / np.where(a > 1e-6, a, 1.0), 0.5 - a * a / 48.0)
    return np.concatenate([rv * k, np.cos(0.5 * a)], axis=-1)


# Left-multiplication matrix of a quaternion a = (x, y, z, w): L(a) @ b = a * b (Hamilton), L(a) L(b) = L(a * b).
_L_INDEX = np.array([3, 2, 1, 0, 2, 3, 0, 1, 1, 0, 3, 2, 0, 1, 2, 3])
_L_SIGN = np.array([1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1, 1, -1, -1, -1, 1], dtype=np.float64)
#: compose_rotations multiplies 4x4 matrices up to this many quaternions (fewest numpy calls), then components
#: (numpy's stacked small-matrix products each cost a fixed overhead, which many of them add up to)
_SCAN_MATRICES_UP_TO = 1024


def compose_rotations(q0: np.ndarray, d_rot: np.ndarray) -> np.ndarray:
    """Orientations after world-fixed rotation increments: q_0 = q0, q_{t+1} = Exp(d_rot[:, t]) q_t.

    The rotations of integrate_in_world (which composes rotation matrices, then converts them) in a fraction of
    the time. Rows whose increments all turn about the world z axis (the Predictor's roll-outs that keep their
    support face) are q0 turned by the running yaw, one product per step; the others are a parallel prefix
    product (log2(H + 1) batched products) of the quaternions, for few of them as their left-multiplication
    matrices (the last column of L(q_t) is q_t), else component-wise. Plain numpy on purpose, not
    scipy.spatial.transform (used elsewhere): this is the Predictor's batch-1 hot path, scipy has no prefix
    product, and Rotation.from_rotvec is slower than _exp_map. test_geometry_scipy checks both against scipy,
    test_rollout_kernels all three branches against integrate_in_world.

    Args:
        q0: (B, 4) start orientations (x, y, z, w; normalised here).
        d_rot: (B, H, 3) rotation vectors in world axes.

    Returns:
        (B, H + 1, 4) unit quaternions with w >= 0.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    d_rot = np.asarray(d_rot, dtype=np.float64)
    q0 = q0 / np.sqrt(np.sum(q0 * q0, axis=-1, keepdims=True))
    general = np.flatnonzero(np.any(d_rot[..., :2] != 0.0, axis=(1, 2)))
    if len(general) == len(q0):
        out = _prefix_product(q0, d_rot)
    else:  # the running yaw costs less for all rows than selecting some
        out = _turned_about_z(q0, d_rot[..., 2])
        if len(general):
            out[general] = _prefix_product(q0[general], d_rot[general])
    return out * (np.where(out[..., 3:] < 0, -1.0, 1.0) / np.sqrt(np.sum(out * out, axis=-1, keepdims=True)))


def _turned_about_z(q0: np.ndarray, d_yaw: np.ndarray) -> np.ndarray:
    """(B, H + 1, 4) orientations q0 (B, 4) turned about the world z axis by the running sums of d_yaw (B, H):
    turns about one axis add, so each is one Hamilton product (0, 0, sin(yaw/2), cos(yaw/2)) * q0."""
    half = np.zeros((len(q0), d_yaw.shape[1] + 1))
    np.cumsum(0.5 * d_yaw, axis=1, out=half[:, 1:])
    s, c = np.sin(half), np.cos(half)
    x, y, z, w = (q0[:, i, None] for i in range(4))
    return np.stack([c * x - s * y, c * y + s * x, c * z + s * w, c * w - s * z], -1)


def _prefix_product(q0: np.ndarray, d_rot: np.ndarray) -> np.ndarray:
    """compose_rotations' general rows, unnormalised: unit q0 (B, 4), d_rot (B, H, 3) -> (B, H + 1, 4)."""
    q = np.concatenate([q0[:, None], _exp_map(d_rot)], axis=1)
    n, k = q.shape[1], 1
    if q.shape[0] * n <= _SCAN_MATRICES_UP_TO:
        acc = (q[..., _L_INDEX] * _L_SIGN).reshape(q.shape[:2] + (4, 4))
        while k < n:  # later factors on the left keep the time order: acc[i] <- acc[i] @ acc[i - k]
            acc[:, k:] = np.einsum("bnij,bnjk->bnik", acc[:, k:], acc[:, :-k])
            k *= 2
        return acc[..., 3]
    x, y, z, w = (np.ascontiguousarray(q[..., i]) for i in range(4))
    while k < n:  # q[i] <- q[i] * q[i - k] (Hamilton product, geometry.quat_multiply's formula)
        ax, ay, az, aw = x[:, k:], y[:, k:], z[:, k:], w[:, k:]
        bx, by, bz, bw = x[:, :-k], y[:, :-k], z[:, :-k], w[:, :-k]
        x[:, k:], y[:, k:], z[:, k:], w[:, k:] = (aw * bx + ax * bw + ay * bz - az * by,
                                                  aw * by - ax * bz + ay * bw + az * bx,
                                                  aw * bz + ax * by - ay * bx + az * bw,
                                                  aw * bw - ax * bx - ay * by - az * bz)
        k *= 2
    return np.stack([x, y, z, w], -1)
