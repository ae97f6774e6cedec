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
