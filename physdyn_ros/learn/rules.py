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
"""Physical consistency of predicted trajectories, applied to every roll-out the Predictor (and `physdyn
evaluate`) returns: numpy only.

A network's outputs need not obey what physics makes certain: a stopped object stays stopped on a flat table,
and a topple is not undone. These rules make the outputs agree with that (without them velocities need never
reach zero, and a topple probability can disagree with the predicted poses).
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from ..conventions import DT, REST_ANG_VEL, REST_LIN_VEL, TOPPLE_ANGLE


#: The whole-push topple head's probability is for the whole push (simulations of 5 s): roll-outs with a head take
#: the per-step timing from at least this many steps (4 s) and return the requested prefix, so a short horizon
#: does not squeeze the whole probability into its few steps.
HEAD_TIMING_STEPS = 60


def tilted_past(orientations: np.ndarray) -> np.ndarray:
    """(B, H+1) bool: the pose's up axis is tilted past TOPPLE_ANGLE (orientations (B, H+1, 4) x, y, z, w)."""
    x, y = orientations[..., 0], orientations[..., 1]
    return 1.0 - 2.0 * (x * x + y * y) < np.cos(TOPPLE_ANGLE)  # the up axis' z component (geometry.up_tilt_angle)


def consistent_topple(prob: np.ndarray, orientations: np.ndarray) -> np.ndarray:
    """Per-step topple probabilities (B, H+1) that agree with the predicted poses: a topple cannot be undone (the
    probability never decreases along a trajectory), and a predicted pose tilted past TOPPLE_ANGLE has toppled
    (probability 1 from there on)."""
    return np.maximum.accumulate(np.where(tilted_past(orientations), 1.0, prob), axis=1)


def whole_push_topple(step_prob: np.ndarray, head: np.ndarray, tilted: np.ndarray,
                      fuse: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-step probabilities (B, H+1) whose maximum is the whole-push probability of the topple head (B,), or 1
    where the roll-out's own poses tilt past TOPPLE_ANGLE (tilted (B, H+1)); the steps keep the per-step
    network's timing (its running maximum, scaled to reach that probability); frame 0 stays 0. `fuse` maps
    that whole-push probability to another (the predictor's topple fusion with physics). Returns (per step,
    whole)."""
    whole = np.maximum(np.asarray(head, dtype=np.float64), tilted.any(axis=1))
    if fuse is not None:
        whole = np.asarray(fuse(whole), dtype=np.float64)
    running = np.maximum.accumulate(np.maximum(step_prob[:, 1:], 1e-12), axis=1)
    timing = running / running[:, -1:]
    per_step = np.zeros(step_prob.shape)
    per_step[:, 1:] = whole[:, None] * timing
    return per_step, whole


def settle(d_pos: np.ndarray, d_rot: np.ndarray, lin: np.ndarray, ang: np.ndarray, first: int = 1,
           dt: float = DT) -> np.ndarray:
    """The rest rule on predictions, in place: from the first state j >= `first` that is quiet (its speeds under
    REST_LIN_VEL / REST_ANG_VEL, or the step into it moved less than they allow in dt), the object stays where it
    is with exactly zero velocity: the steps after j move nothing and the velocities of states >= j are zero.
    (A network's fed-back velocity can keep an offset after its poses have stopped; on a flat table static
    friction holds a stopped object.) d_pos, d_rot (B, H, 3); lin, ang (B, H+1, 3). Returns j per row (H+1: never).
    """
    quiet_state = (_norm2(lin) < REST_LIN_VEL ** 2) & (_norm2(ang) < REST_ANG_VEL ** 2)
    quiet_step = (_norm2(d_pos) < (REST_LIN_VEL * dt) ** 2) & (_norm2(d_rot) < (REST_ANG_VEL * dt) ** 2)
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


def _norm2(v: np.ndarray) -> np.ndarray:
    """Squared lengths of 3-vectors (..., 3), by components (a numpy reduction over 3 entries costs 10x this)."""
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2]


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


def topple_with_head(prob: np.ndarray, head: np.ndarray, d_rot: np.ndarray, ang: np.ndarray, first: int,
                     orientations: Callable[[np.ndarray, np.ndarray], np.ndarray],
                     fuse: Optional[Callable[[np.ndarray], np.ndarray]] = None) -> np.ndarray:
    """The whole-push topple head's verdict on a roll-out, in place on d_rot / ang (after flat_unless_toppling
    with the per-step probabilities `prob`): per-step probabilities with the head's maximum (whole_push_topple,
    a pose tilted past TOPPLE_ANGLE counting as toppled), and no tilt where that maximum is at most 0.5 (the
    head's "no" also removes a tilt the per-step network allowed). Steps before `first` are observed and kept;
    orientations(rows, d_rot[rows]) integrates the given rows' rotation increments to (len(rows), H+1, 4) poses
    (called for the rows that tilt only); `fuse` as whole_push_topple's. Returns the per-step probabilities
    (B, H+1)."""
    tilted = np.zeros(prob.shape, dtype=bool)
    free = np.flatnonzero(np.any(d_rot[..., :2] != 0.0, axis=(1, 2)))  # rows the step network let tilt
    if len(free):
        tilted[free] = tilted_past(orientations(free, d_rot[free]))
    per_step, whole = whole_push_topple(prob, head, tilted, fuse)
    flat_unless_toppling(d_rot[:, first:], ang[:, first:], whole[:, None])
    return per_step
