"""Physical consistency of predicted trajectories, applied to every roll-out the Predictor (and `physdyn
evaluate`) returns: numpy only.

A network's outputs need not obey what physics makes certain: a stopped object stays stopped on a flat table,
and a topple is not undone. These rules make the outputs agree with that (issue 11: velocities that never
reached zero, a topple probability that disagreed with the predicted poses).
"""
from __future__ import annotations

import numpy as np

from ..conventions import DT, REST_ANG_VEL, REST_LIN_VEL, TOPPLE_ANGLE


def consistent_topple(prob: np.ndarray, orientations: np.ndarray) -> np.ndarray:
    """Per-step topple probabilities (B, H+1) that agree with the predicted poses: a topple cannot be undone (the
    probability never decreases along a trajectory), and a predicted pose tilted past TOPPLE_ANGLE has toppled
    (probability 1 from there on)."""
    x, y = orientations[..., 0], orientations[..., 1]
    tilted = 1.0 - 2.0 * (x * x + y * y) < np.cos(TOPPLE_ANGLE)  # the up axis' z component (geometry.up_tilt_angle)
    return np.maximum.accumulate(np.where(tilted, 1.0, prob), axis=1)


def settle(d_pos: np.ndarray, d_rot: np.ndarray, lin: np.ndarray, ang: np.ndarray, first: int = 1,
           dt: float = DT) -> np.ndarray:
    """The rest rule on predictions, in place: from the first state j >= `first` that is quiet (its speeds under
    REST_LIN_VEL / REST_ANG_VEL, or the step into it moved less than they allow in dt), the object stays where it
    is with exactly zero velocity: the steps after j move nothing and the velocities of states >= j are zero.
    (A network's fed-back velocity can keep an offset after its poses have stopped; on a flat table static
    friction holds a stopped object.) d_pos, d_rot (B, H, 3); lin, ang (B, H+1, 3). Returns j per row (H+1: never).
    """
    quiet_state = (np.linalg.norm(lin, axis=-1) < REST_LIN_VEL) & (np.linalg.norm(ang, axis=-1) < REST_ANG_VEL)
    quiet_step = ((np.linalg.norm(d_pos, axis=-1) < REST_LIN_VEL * dt)
                  & (np.linalg.norm(d_rot, axis=-1) < REST_ANG_VEL * dt))
    quiet = quiet_state.copy()
    quiet[:, 1:] |= quiet_step
    quiet[:, :max(first, 1)] = False
    horizon = d_pos.shape[1]
    rest = np.where(quiet.any(axis=1), quiet.argmax(axis=1), horizon + 1)
    state_idx = np.arange(horizon + 1)[None, :]
    still_state = state_idx >= rest[:, None]
    lin[still_state] = 0.0
    ang[still_state] = 0.0
    still_step = state_idx[:, :horizon] >= rest[:, None]  # step t leads from state t to t + 1
    d_pos[still_step] = 0.0
    d_rot[still_step] = 0.0
    return rest


def flat_unless_toppling(d_rot: np.ndarray, ang: np.ndarray, prob: np.ndarray,
                         threshold: float = 0.5) -> np.ndarray:
    """No phantom tilt, in place: a trajectory whose topple probability stays at or below `threshold` keeps the
    support face it started on, so its rotation increments and angular velocities become pure yaw (the x, y
    components of world-fixed rotation vectors and of the angular velocity after the first state set to zero;
    the start orientation's own tilt is kept). d_rot (B, H, 3), ang (B, H+1, 3) with z up; prob (B, H+1) or (B, H).
    Returns the rows that may topple (left as predicted)."""
    toppling = np.max(prob, axis=1) > threshold
    flat = ~toppling
    d_rot[flat, :, :2] = 0.0
    ang[flat, 1:, :2] = 0.0
    return toppling
