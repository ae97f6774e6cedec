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
"""Object poses and twists from the clouds themselves, and push onsets (numpy and scipy; no ROS).

Per tracked object (its id from tracking.Tracker):
* reference: when first seen, its surface becomes an `ObjectModel` (registration.py) in the object's frame, whose
  origin is the centre-of-mass estimate and whose axes are the table's at that instant: the published
  orientation is the rotation since the reference was captured (identity then), as Predictor.rollout takes
  orientations. The caller gives the surface (the perception node: every point of the cloud near the object's
  cluster, `Scene.surface`; a model of one cloud's random sample leaves the next sample's points millimetres off
  it, and the fit slides to explain them) and the centre of mass (the node: `footprint_com` of that surface, or
  the encoder's head); without them, the detection's points and their `footprint_com`. A one-sided view misplaces
  the centre of mass; with `refine_com`, once the object has turned and the model has grown by the sides that came
  into view, `footprint_com` of the model's points seen in several clouds becomes the origin (COM_TURN);
* pose at every cloud: the object's points registered to the model (point-to-plane ICP) from the
  constant-velocity prediction and, when the points' centroid moved away from its prediction, from that pose
  moved by the shift too (the first cloud of a push is far from any prediction); the shifted guess wins only
  when it explains clearly more points or its `misfit` is clearly the lower; a fit that explains too few points
  keeps the track but reports low confidence and the reason; a fit that explains the cloud no better than the
  last pose keeps that pose; the points of a fit close to its guess (the pose held, or the motion predicted)
  that fit well and lie off the model grow it;
* twist: from the last `window` poses of the push (positions, and rotation vectors relative to the newest
  orientation) within `window_time`: a least-squares line, with the speed along it and the yaw rate from a
  parabola's slope at the newest pose (the line's is the mean over the window, which a slide at 15 Hz outruns by
  up to 0.5 m/s); a line's through two; its first cloud's line runs through the rest pose before it. Zero-mean
  sensor noise averages out; at rest it is zero. The predictor refines a push's prediction with these states;
* onset (rest -> moving): the object is at rest while its pose stays within `onset_distance` / `onset_angle` of its
  rest pose; the first cloud beyond that opens a push. Once `onset_frames` moving clouds are in (or the object
  rests again) and the pose has left the rest pose by twice the threshold (CONFIRM; else, within CONFIRM_FRAMES
  more clouds, the step was the estimate's and the new pose is the rest pose), the push's start is fitted
  (`fit_onset`): a slide under Coulomb friction from the rest pose, s(tau) = v0 tau - a tau^2 / 2 until it stops,
  with the onset instant t0, v0 and the spin w0 as unknowns (a, the deceleration, is `deceleration` unless enough
  clouds fix it). The state at t0 (the rest pose) with the twist (v0, w0) is reported once as the push's initial
  state. The object rests again once its last `rest_frames` poses lie within `rest_distance` and `rest_angle` of
  the newest (an object turned in place keeps its position but moves).

Bad input: a stamp not after the previous one (a frozen sensor sends the same cloud twice) is skipped with the
reason; time going back by more than `max_gap` (a replayed bag) drops every track; after a gap longer than
`max_gap` without a pose (no cloud, or fits below `min_inliers`) the motion history is dropped (the prediction is
stale), the pose is registered from the last one and is the new rest pose (no push is inferred across the gap);
a partial view (the object half out of view, a hand in front) keeps the track with confidence = the share of
points the model explains, and a fit that explains fewer than `min_inliers` leaves the pose as it was.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .registration import INLIER_DISTANCE, Fit, ObjectModel, register
from .revolution import revolution_axis
from .scene import hull_centroid

G = 9.81  # m/s^2
#: Where a new track's centre of mass comes from (the perception node's track_com): footprint_com, or the
#: encoder's centre-of-mass head.
COM_SOURCES = ("footprint", "model")
#: footprint_com takes the top faces' outline for the footprint where its area is this share of the view's outline's
TOP_SPAN = 0.7
#: ... and keeps a surface of revolution's axis there only within this (m) of that outline's centroid.
AXIS_AGREEMENT = 0.003
#: m: the top's flat part, whose outline's centroid top_outline_xy takes, lies this close to its median height
TOP_FLAT = 0.0015
#: points a top (or its flat part) needs for its outline to count: fewer are a stray point's few neighbours
TOP_POINTS = 20


@dataclass
class PoseConfig:
    """Pose-tracking settings (the perception node's track_* parameters)."""

    window: int = 4  # poses of the twist's fit
    window_time: float = 0.5  # s: older poses are not part of the fit
    icp_points: int = 200  # observed points registered per object (a random subset)
    icp_iterations: int = 10
    tilt: bool = True  # False: yaw and translation only (objects that stay upright)
    model_voxel: float = 0.003  # m
    model_points: int = 3000
    min_inliers: float = 0.35  # share of points the model must explain for the pose to count as measured
    onset_distance: float = 0.004  # m from the rest pose
    onset_angle: float = math.radians(3.0)  # rad from the rest orientation
    onset_frames: int = 2  # moving clouds before the push's initial state is fitted
    rest_frames: int = 3  # clouds within rest_distance and rest_angle of the newest: at rest again
    rest_distance: float = 0.002  # m
    rest_angle: float = math.radians(2.0)  # rad: an object turning in place (from 0.25 rad/s at 15 Hz) moves
    deceleration: float = 0.5 * G  # m/s^2: Coulomb friction mu g with mu 0.5 when the clouds cannot tell
    max_gap: float = 1.0  # s without a cloud: the motion history is dropped


#: A push is reported once its pose has left the rest pose by this many onset thresholds (distance or angle);
#: a pose that stepped past one threshold and stays there within CONFIRM_FRAMES more clouds is the estimate's jump
#: (partial views), not a push. A real push at 0.3 m/s moves 2 cm per cloud at 15 Hz; a 5 cm/s creep passes
#: twice the 4 mm threshold within three clouds.
CONFIRM = 2.0
CONFIRM_FRAMES = 2
#: A track keeps its last pose unless the registration explains the new cloud clearly better: more than this much
#: more of its points (share), or a residual below the last pose's by more than HOLD_RMSE and HOLD_RMSE_ABS (m).
HOLD_INLIERS = 0.02
HOLD_RMSE = 1.1
HOLD_RMSE_ABS = 0.0002
#: The guess moved by the centroid's shift replaces the prediction's fit only when it explains clearly more of the
#: points (GUESS_INLIERS more) or explains them clearly more closely: its misfit below GUESS_MARGIN times the
#: prediction's, less GUESS_MARGIN_ABS (m^2). On a dense model a fit that stays behind a slide along a large face
#: still explains nearly every point (within the inlier distance), only less closely; at rest, residuals of a few
#: tenths of a millimetre differ by noise alone, and a view that leaves a slide along a face free fits as well
#: wherever the shifted guess starts.
GUESS_INLIERS = 0.02
GUESS_MARGIN = 0.8
GUESS_MARGIN_ABS = 1e-7
#: A fit grows the model only when it stays within GROW_TURN (rad) and GROW_SHIFT (m) of its starting guess.
GROW_TURN = math.radians(1.0)
GROW_SHIFT = 0.002
#: An object at rest that has turned by COM_TURN (rad), and whose model points seen in COM_HITS clouds
#: (ObjectModel.hits, counted at poses that fit) have grown by COM_GROWTH since its centre of mass was estimated,
#: gets a new estimate from those points: the sides a push turned into view (one view of a wedge with its slope
#: away from the camera puts the centre of mass 1.5 cm towards it). A depth camera's mixed pixels that joined the
#: model gain hardly any hits. Without a turn the model only grows denser on the same view, and its estimate would
#: wander by millimetres. A change below COM_STEP (m) is not applied.
COM_TURN = math.radians(20.0)
COM_GROWTH = 1.2
COM_STEP = 0.001
COM_HITS = 5


@dataclass
class TrackedState:
    """One object's state at one cloud (or at a push's onset): table frame, SI units."""

    object_id: str
    t: float  # s
    position: np.ndarray  # (3,) m, the centre-of-mass estimate
    orientation: np.ndarray  # (4,) x, y, z, w: rotation since the reference was captured
    linear: np.ndarray  # (3,) m/s
    angular: np.ndarray  # (3,) rad/s
    moving: bool
    confidence: float  # 0..1, the share of the object's points its model explains
    note: str = ""  # why the pose is uncertain, or what happened


@dataclass
class PoseUpdate:
    """What one cloud gave: a state per tracked object, the onsets found, and the clouds or objects skipped."""

    states: list[TrackedState] = field(default_factory=list)
    onsets: list[TrackedState] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def top_outline_xy(points: np.ndarray) -> np.ndarray | None:
    """x-y (2,) area centroid of the convex hull of the x-y projection of a view's flat top, or None unless the
    top faces' hull (the points within 5 mm of the top, the 99.5th percentile of the heights: a stray point above
    it does not count) has at least TOP_SPAN of the whole view's area (a box, a cylinder, a prism standing on the
    table: the camera sees the top whole and it is the footprint). The centroid is that of the points within
    TOP_FLAT (or three times their spread, under sensor noise) of the top faces' median height: a rounded or
    bevelled rim shows its near side to the camera and hides its far side, and would pull the centroid towards
    the camera."""
    pts = np.asarray(points, dtype=np.float64)
    z = pts[:, 2]
    band = z >= np.percentile(z, 99.5) - 0.005
    if band.sum() < TOP_POINTS:
        return None
    # the top faces only: the side faces the camera sees lie on the footprint's near edge, densely, while its
    # far edge is sampled by the top face alone, which would pull the centroid of every point towards the camera
    top, whole = hull_centroid(pts[band, :2]), hull_centroid(pts[:, :2])
    if top is None or whole is None or top[1] < TOP_SPAN * whole[1]:
        return None
    level = float(np.median(z[band]))
    spread = 1.4826 * float(np.median(np.abs(z[band] - level)))
    flat = band & (np.abs(z - level) <= max(TOP_FLAT, 3.0 * spread))
    inner = hull_centroid(pts[flat, :2]) if flat.sum() >= TOP_POINTS else None
    return np.asarray((top if inner is None else inner)[0], dtype=np.float64)


def footprint_com(points: np.ndarray, table_height: float = 0.0) -> np.ndarray:
    """Centre-of-mass estimate of an upright object from a partial view. x-y: the axis of a surface of revolution
    where the view is one (a bottle, a can, a ball; revolution.revolution_axis), unless the top faces' outline
    spans the footprint (top_outline_xy) and its centroid lies more than AXIS_AGREEMENT from the axis (a round
    front on a flat or oval back: the outline sees the whole top); else that outline's centroid; else, where the
    top is an edge or a point (a wedge, a pyramid), column_com's. The height is column_com's (half the top's for a
    prism, a third for a wedge)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"footprint_com needs points of shape (N, 3), got {pts.shape}")
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        raise ValueError("footprint_com needs at least one finite point")
    column = column_com(pts, table_height)
    axis, top = revolution_axis(pts, table_height), top_outline_xy(pts)
    if axis is not None and (top is None or np.linalg.norm(axis - top) <= AXIS_AGREEMENT):
        return np.array([axis[0], axis[1], column[2]])
    return column if top is None else np.array([top[0], top[1], column[2]])


def misfit(fit: Fit) -> float:
    """Mean squared point-to-plane residual over all the fit's points, an outlier counting as the inlier
    distance (m^2): how many points the model explains and how closely, in one number."""
    if fit.inliers <= 0.0 or not math.isfinite(fit.rmse):
        return INLIER_DISTANCE ** 2
    return fit.inliers * fit.rmse ** 2 + (1.0 - fit.inliers) * INLIER_DISTANCE ** 2


def column_com(points: np.ndarray, table_height: float = 0.0, cell: float = 0.003) -> np.ndarray:
    """Centre of the solid under a view's surface: the highest point per `cell` (m) in x-y, a piecewise-linear
    height field over their Delaunay triangles, each column filled down to the table. Exact for shapes whose
    sides fall straight or inward to the table (boxes, cylinders, wedges, pyramids) when the camera sees their
    top; its height is the right one for a wedge or a pyramid, where half the top's is too high."""
    from scipy.spatial import Delaunay, QhullError

    pts = np.asarray(points, dtype=np.float64)
    _, inv = np.unique(np.floor(pts[:, :2] / cell).astype(np.int64), axis=0, return_inverse=True)
    inv = inv.ravel()
    top = np.full(inv.max() + 1, -np.inf)
    np.maximum.at(top, inv, pts[:, 2] - table_height)
    xy = np.zeros((len(top), 2))
    np.add.at(xy, inv, pts[:, :2])
    xy /= np.bincount(inv)[:, None]
    h = np.maximum(top, 0.0)
    try:
        tri = Delaunay(xy).simplices
    except (QhullError, ValueError):
        return np.array([*xy.mean(axis=0), table_height + 0.5 * float(h.max())])
    a, b, c = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1]))
    ht = h[tri]  # (T, 3) heights at the corners
    volume = area * ht.mean(axis=1)
    if volume.sum() <= 0.0:
        return np.array([*xy.mean(axis=0), table_height])
    # a column with a linear top: its x-y centroid weights corner i by (h0 + h1 + h2 + h_i), its z centroid is
    # the integral of h^2 / 2 over the triangle
    weights = ht.sum(axis=1, keepdims=True) + ht
    weights[weights.sum(axis=1) <= 0.0] = 1.0  # a flat triangle on the table: no volume, any finite centre
    centre_xy = (weights[:, :, None] * xy[tri]).sum(axis=1) / weights.sum(axis=1, keepdims=True)
    half_h2 = area * ((ht ** 2).sum(axis=1) + ht[:, 0] * ht[:, 1] + ht[:, 1] * ht[:, 2] + ht[:, 0] * ht[:, 2]) / 12.0
    total = float(volume.sum())
    return np.array([*((volume[:, None] * centre_xy).sum(axis=0) / total), table_height + half_h2.sum() / total])


def _line_velocity(ts: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Slope (per s) of least-squares lines through values (n, d) at times ts (n,)."""
    tc = ts - ts.mean()
    den = float(tc @ tc)
    return (tc @ (values - values.mean(axis=0))) / den if den > 0 else np.zeros(values.shape[1])


def first_cloud_velocity(tau: float, start_position: np.ndarray, start_orientation: np.ndarray,
                         start_lin: np.ndarray, start_ang: np.ndarray, position: np.ndarray,
                         orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear and angular velocity (3,) at a push's first observed state, tau s after its onset, from the pose's
    change since the onset (position (3,), orientation x, y, z, w) and the onset's velocity. At a push's first
    cloud the tracker's twist runs through one pose of the push and the rest pose before it: its mean since the
    rest cloud, not its velocity at the stamp; under constant deceleration the mean since the onset is the average
    of the two velocities. A velocity against the onset's (the slide stopped before the cloud) is zero."""
    if not tau > 0:
        raise ValueError(f"the observed state must come after the onset, got {tau:g} s")
    lin = 2.0 * (np.asarray(position, dtype=np.float64) - start_position) / tau - start_lin
    lin[2] = 0.0  # the slide is along the table
    turn = (Rotation.from_quat(orientation) * Rotation.from_quat(start_orientation).inv()).as_rotvec()
    ang = 2.0 * turn / tau - np.asarray(start_ang, dtype=np.float64)
    # a slide that stopped before the cloud (or a pose the cloud did not move) would read a reversed velocity
    return (lin if float(lin @ start_lin) > 0.0 else np.zeros(3)), (ang if float(ang @ start_ang) > 0.0
                                                                   else np.zeros(3))


def _end_rate(ts: np.ndarray, values: np.ndarray, line_rate: float) -> float:
    """Rate (per s) at the newest of ts of a least-squares parabola through values (n,), n >= 3; 0 where it runs
    against the line's rate (a slide that stopped within the window)."""
    tc = ts - ts[-1]
    rate = float(np.linalg.lstsq(np.stack([np.ones_like(tc), tc, tc * tc], axis=1), values, rcond=None)[0][1])
    return rate if rate * line_rate > 0.0 else 0.0


def _turn(rotation: np.ndarray, reference: np.ndarray) -> float:
    """Angle (rad) of the rotation from `reference` to `rotation` (3 x 3 matrices): atan2 of its sine (half the
    norm of the skew part) and cosine (from the trace), accurate at small angles; a scipy Rotation per call cost
    a quarter of a millisecond, several times per object and cloud."""
    m = rotation @ reference.T
    sine = 0.5 * math.sqrt((m[2, 1] - m[1, 2]) ** 2 + (m[0, 2] - m[2, 0]) ** 2 + (m[1, 0] - m[0, 1]) ** 2)
    return math.atan2(sine, 0.5 * (float(np.trace(m)) - 1.0))


def _slide(tau: np.ndarray, v0: float, a: float) -> np.ndarray:
    """Distance slid tau s after the onset at speed v0 decelerating at a (stopped at v0 / a); 0 before."""
    tau = np.clip(tau, 0.0, v0 / a if a > 0 else np.inf)
    return v0 * tau - 0.5 * a * tau * tau


def fit_onset(ts: np.ndarray, disp: np.ndarray, rot: np.ndarray, t_rest: float, deceleration: float
              ) -> tuple[float, np.ndarray, np.ndarray]:
    """The onset instant t0 (s), the velocity v0 (3,) and the spin w0 (3,) right after it, from the
    displacements disp (n, 3) and rotation vectors rot (n, 3) relative to the rest pose at the moving clouds' times
    ts (n,); t_rest is the last cloud at rest (t0 lies after it).

    The slide follows a constant deceleration along its direction until it stops (see the module docstring);
    with three or more moving clouds the deceleration is fitted too, else `deceleration` is used. The spin
    decelerates in the same proportion (both come from the friction at the base), which is exact for a
    translating block and a fair approximation for a spinning one."""
    from scipy.optimize import least_squares

    dist = np.linalg.norm(disp, axis=1)
    direction = disp[-1] / dist[-1] if dist[-1] > 1e-9 else np.array([1.0, 0.0, 0.0])
    s = disp @ direction
    t1 = float(ts[0])
    span = max(1e-3, t1 - t_rest)
    fit_a = len(ts) >= 3

    def residual(x: np.ndarray) -> np.ndarray:
        t0, v0 = x[0], x[1]
        a = x[2] if fit_a else deceleration
        return _slide(ts - t0, v0, a) - s

    guess_v = max(1e-3, float(s[0]) / max(1e-3, t1 - (t_rest + 0.5 * span)))
    lo = np.array([t_rest, 0.0] + ([0.0] if fit_a else []))
    hi = np.array([t1 - 1e-4, 50.0] + ([20.0 * G] if fit_a else []))
    x0 = np.clip([t_rest + 0.5 * span, guess_v] + ([deceleration] if fit_a else []), lo + 1e-9, hi - 1e-9)
    sol = least_squares(residual, x0, bounds=(lo, hi))
    t0, v0 = float(sol.x[0]), float(sol.x[1])
    a = float(sol.x[2]) if fit_a else deceleration
    # the spin: the rotation vector grows like the slide (same friction), scaled by w0 / v0
    shape = _slide(ts - t0, max(v0, 1e-6), a) / max(v0, 1e-6)  # s / v0: seconds of "initial-speed motion"
    den = float(shape @ shape)
    w0 = (shape @ rot) / den if den > 1e-12 else np.zeros(3)
    if v0 < 1e-4:  # a pure spin: time the onset by the rotation instead
        w0 = rot[0] / max(1e-3, t1 - t0)
    return t0, v0 * direction, w0


@dataclass
class PoseTrack:
    """One object's pose history, rest pose and push state."""

    object_id: str
    model: ObjectModel
    rotation: np.ndarray  # (3, 3) the latest pose
    position: np.ndarray  # (3,)
    centroid: np.ndarray  # (3,) centroid of the latest observed points (its shift guides the next guess)
    t: float
    history: deque = field(default_factory=lambda: deque(maxlen=16))  # (t, position, rotation)
    rest_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rest_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    rest_t: float = 0.0
    moving: bool = False
    push: list = field(default_factory=list)  # moving clouds of the current push: (t, position, rotation)
    reported: bool = False  # this push's onset is out
    confidence: float = 1.0
    refine: bool = True  # re-estimate the centre of mass from the grown model (footprint_com)
    com_points: int = 0  # the model's size when the centre of mass was last estimated
    com_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # ... and the pose's rotation then


class PoseTracker:
    """Poses, twists and onsets of the objects the id tracker names (see the module docstring)."""

    def __init__(self, config: PoseConfig | None = None, seed: int = 0) -> None:
        self.config = config if config is not None else PoseConfig()
        self.tracks: dict[str, PoseTrack] = {}
        self._rng = np.random.default_rng(seed)
        self._last_t: float | None = None

    def reset(self) -> None:
        self.tracks.clear()
        self._last_t = None

    def forget(self, keep) -> list[str]:
        """Drop the tracks whose ids are not in `keep` (ids the id tracker retired); their ids."""
        gone = [k for k in self.tracks if k not in set(keep)]
        for k in gone:
            del self.tracks[k]
        return gone

    def update(self, t: float, detections, com_of: Callable[[str, np.ndarray], np.ndarray] | None = None,
               table_height: float = 0.0, surface_of: Callable[[str], np.ndarray] | None = None,
               refine_com: bool = True) -> PoseUpdate:
        """detections: (object_id, points (N, 3) table frame) seen in the cloud of time t (s). A track's reference
        is captured on a first sighting or after a reset: surface_of(object_id) gives the points of its model (the
        object as densely as the cloud has it; default: the detection's points), and com_of(object_id, those
        points) its centre-of-mass estimate (3,) (default: footprint_com of them). refine_com: new tracks take
        footprint_com of their grown model at rest (COM_TURN); False keeps com_of's estimate for good."""
        out = PoseUpdate()
        if self._last_t is not None and t < self._last_t - self.config.max_gap:
            out.notes.append(f"time went back from {self._last_t:.3f} s to {t:.3f} s (a replayed bag, a reset clock): "
                             f"{len(self.tracks)} pose track(s) dropped")
            self.reset()
        if self._last_t is not None and t <= self._last_t:
            out.notes.append(f"cloud at t = {t:.3f} s skipped: not after the previous cloud ({self._last_t:.3f} s; "
                             "a frozen sensor or a replayed bag)")
            return out
        self._last_t = t
        for object_id, points in detections:
            pts = np.asarray(points, dtype=np.float64)
            if len(pts) < 10:
                out.notes.append(f"{object_id}: only {len(pts)} points, pose not updated")
                continue
            track = self.tracks.get(object_id)
            if track is None:
                dense = pts if surface_of is None else np.asarray(surface_of(object_id), dtype=np.float64)
                com = footprint_com(dense, table_height) if com_of is None else com_of(object_id, dense)
                track = self._capture(object_id, dense, t, np.asarray(com, dtype=np.float64), pts.mean(axis=0))
                track.refine = refine_com
                out.states.append(self._state(track, "reference captured"))
                continue
            state, onset = self._step(track, pts, t, table_height)
            out.states.append(state)
            if onset is not None:
                out.onsets.append(onset)
        return out

    # --------------------------------------------------------------------------------------------- per track
    def _capture(self, object_id: str, pts: np.ndarray, t: float, com: np.ndarray, centroid: np.ndarray
                 ) -> PoseTrack:
        cfg = self.config
        model = ObjectModel(pts - com, cfg.model_voxel, cfg.model_points)
        track = PoseTrack(object_id, model, np.eye(3), com.copy(), centroid, t, com_points=len(model.points))
        track.history.append((t, com.copy(), np.eye(3)))
        track.rest_position, track.rest_rotation, track.rest_t = com.copy(), np.eye(3), t
        self.tracks[object_id] = track
        return track

    def _guesses(self, track: PoseTrack, t: float, pts: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Starting poses at t: constant velocity (and spin) from the history; when the observed centroid has
        moved away from its prediction (a far-off prediction, the first cloud of a push), also that pose moved by
        the shift. Both: a partial view shifts the centroid without the object moving."""
        dt = t - track.t
        lin, ang = self._twist(track, at_newest=False)
        rot = Rotation.from_rotvec(ang * dt).as_matrix() @ track.rotation
        pos = track.position + lin * dt
        shift = pts.mean(axis=0) - (track.centroid + lin * dt)
        out = [(rot, pos)]
        if float(np.linalg.norm(shift)) > 0.005:
            out.append((rot, pos + shift))
        return out

    def _step(self, track: PoseTrack, pts: np.ndarray, t: float, table_height: float
              ) -> tuple[TrackedState, TrackedState | None]:
        cfg = self.config
        note = ""
        gap = t - track.t > cfg.max_gap
        if gap:  # a stale prediction: start the motion history over
            keep = track.history[-1]
            track.history.clear()
            track.history.append(keep)
            note = f"{t - track.t:.1f} s since the last cloud: motion history reset"
        sub = pts if len(pts) <= cfg.icp_points else pts[self._rng.choice(len(pts), cfg.icp_points, replace=False)]
        fit, guess = None, None
        for rot, pos in self._guesses(track, t, sub):
            trial = register(sub, track.model, rot, pos, iterations=cfg.icp_iterations, tilt=cfg.tilt)
            if fit is None or trial.inliers > fit.inliers + GUESS_INLIERS or (  # else the prediction
                    misfit(trial) < GUESS_MARGIN * misfit(fit) - GUESS_MARGIN_ABS):
                fit, guess = trial, (rot, pos)
        assert fit is not None and guess is not None
        # a registration that explains the points no better than the last pose is noise: on a view that pins a
        # rotation or a slide only weakly (a wedge's slope, an object cut by the image's edge) it creeps, and the
        # twist it makes carries the next guess further
        still = register(sub, track.model, track.rotation, track.position, iterations=0, tilt=cfg.tilt)
        if still.inliers >= fit.inliers - HOLD_INLIERS and still.rmse <= HOLD_RMSE * fit.rmse + HOLD_RMSE_ABS:
            fit, guess = still, (track.rotation, track.position)
        track.confidence = fit.inliers
        if fit.inliers < cfg.min_inliers:
            # the pose and its centroid stay as they were: the next guess adds the whole shift since then
            note = (f"{note}; " if note else "") + (f"pose uncertain: the model explains {100 * fit.inliers:.0f} % of "
                                                    "the points (occluded, half out of view or another object)")
            return self._state(track, note), None
        track.centroid = pts.mean(axis=0)
        track.rotation, track.position, track.t = fit.rotation, fit.translation, t
        track.history.append((t, fit.translation.copy(), fit.rotation.copy()))
        if gap:
            # nothing is known of the motion across the gap: the pose found is the new rest pose, and no push is
            # inferred from poses seconds apart (a fragment of a cluster seen now and then drifts from sighting to
            # sighting)
            track.history.clear()
            track.history.append((t, fit.translation.copy(), fit.rotation.copy()))
            track.moving, track.push, track.reported = False, [], False
            track.rest_position, track.rest_rotation, track.rest_t = fit.translation.copy(), fit.rotation.copy(), t
        turn = _turn(fit.rotation, guess[0])
        if fit.rmse < 0.0025 and turn < GROW_TURN and float(np.linalg.norm(fit.translation - guess[1])) < GROW_SHIFT:
            # new faces join the model only at a pose the motion predicted: points added at a pose that a fit
            # turned a few degrees off pull the next fits further off (a yaw that ran away by 100 deg in 25 clouds)
            track.model.grow((sub - fit.translation) @ fit.rotation)
            track.model.observe((pts - fit.translation) @ fit.rotation, upto=COM_HITS)
        onset = self._onset(track)
        if not track.moving:
            seen = track.model.hits >= COM_HITS
            if track.refine and int(seen.sum()) >= COM_GROWTH * track.com_points and _turn(
                    track.rotation, track.com_rotation) >= COM_TURN:
                self._refine_com(track, track.model.points[seen], table_height)
        return self._state(track, note), onset

    def _refine_com(self, track: PoseTrack, seen: np.ndarray, table_height: float) -> None:
        """footprint_com of the model's points `seen` at the current pose becomes the track's origin. The model's
        points, the pose history and the rest pose move with it, so that no motion, twist or onset comes of the
        step."""
        track.com_points, track.com_rotation = len(seen), track.rotation.copy()
        rot = track.rotation
        com = footprint_com(seen @ rot.T + track.position, table_height)
        if float(np.linalg.norm(com - track.position)) < COM_STEP:
            return
        offset = rot.T @ (com - track.position)  # model frame
        track.model.move_origin(offset)
        track.position = track.position + rot @ offset
        track.history = deque(((t, p + r @ offset, r) for t, p, r in track.history), maxlen=track.history.maxlen)
        track.rest_position = track.rest_position + track.rest_rotation @ offset

    def _twist(self, track: PoseTrack, at_newest: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Fit through the recent poses (see the module docstring); zero at rest or with one pose. at_newest (the
        published twist): the push's own poses only, at the newest one's instant; False: the mean motion of the
        recent poses, a line (the registration's constant-velocity guess)."""
        cfg = self.config
        hist = [h for h in list(track.history)[-cfg.window:] if h[0] >= track.t - cfg.window_time]
        if not track.moving:
            return np.zeros(3), np.zeros(3)
        pushed = [h for h in hist if h[0] > track.rest_t]
        own = at_newest and len(pushed) >= 2
        if at_newest:  # the rest poses before a push read a fraction of its speed (a model fed that state stops
            # the slide early): its own poses, or its first with the last at rest
            hist = pushed if own else [h for h in hist if h[0] >= track.rest_t]
        if len(hist) < 2:
            return np.zeros(3), np.zeros(3)
        ts = np.array([h[0] for h in hist])
        pos = np.array([h[1] for h in hist])
        ref = hist[-1][2]
        rv = np.array([Rotation.from_matrix(h[2] @ ref.T).as_rotvec() for h in hist])
        lin, ang = _line_velocity(ts, pos), _line_velocity(ts, rv)
        if own and len(ts) >= 3:  # a line's slope is the velocity at the poses' mean time, a parabola's at the
            # newest pose's, where a slide has slowed since: the speed along the line's direction and the yaw rate
            # (a parabola amplifies the poses' noise: the direction and the tilt rates stay the line's)
            speed = float(np.linalg.norm(lin[:2]))
            if speed > 0.0:
                u = lin[:2] / speed
                lin = np.array([*(u * _end_rate(ts, pos[:, :2] @ u, speed)), lin[2]])
            ang = np.array([ang[0], ang[1], _end_rate(ts, rv[:, 2], float(ang[2]))])
        return lin, ang

    def _onset(self, track: PoseTrack) -> TrackedState | None:
        cfg = self.config
        t, pos, rot = track.history[-1]
        off = float(np.linalg.norm(pos - track.rest_position))
        turn = _turn(rot, track.rest_rotation)
        if not track.moving:
            if off > cfg.onset_distance or turn > cfg.onset_angle:
                track.moving, track.push, track.reported = True, [(t, pos, rot)], False
            else:  # at rest: the rest pose follows the mean of the latest poses (noise averages out)
                track.rest_position = 0.8 * track.rest_position + 0.2 * pos
                track.rest_t = t
                return None
        elif track.push and not track.reported:
            track.push.append((t, pos, rot))
        onset = None
        recent = list(track.history)[-cfg.rest_frames:]
        still = len(recent) >= cfg.rest_frames and all(
            float(np.linalg.norm(h[1] - recent[-1][1])) < cfg.rest_distance
            and _turn(h[2], recent[-1][2]) < cfg.rest_angle for h in recent)
        if track.push and not track.reported and (len(track.push) >= cfg.onset_frames or still):
            if off >= CONFIRM * cfg.onset_distance or turn >= CONFIRM * cfg.onset_angle:
                onset = self._report_onset(track)
            elif still or len(track.push) >= cfg.onset_frames + CONFIRM_FRAMES:
                # the pose stepped past the threshold and no further: the estimate moved (another side of the
                # object in view), not the object. The new pose is the rest pose; no push is reported.
                track.moving, track.push = False, []
                track.rest_position, track.rest_rotation, track.rest_t = pos.copy(), rot.copy(), t
                return None
        if still and track.moving and len(track.history) > cfg.rest_frames:
            track.moving, track.push = False, []
            track.rest_position, track.rest_rotation, track.rest_t = pos.copy(), rot.copy(), t
        return onset

    def _report_onset(self, track: PoseTrack) -> TrackedState:
        cfg = self.config
        track.reported = True
        ts = np.array([p[0] for p in track.push])
        disp = np.array([p[1] for p in track.push]) - track.rest_position
        rot = np.array([Rotation.from_matrix(p[2] @ track.rest_rotation.T).as_rotvec() for p in track.push])
        t0, v0, w0 = fit_onset(ts, disp, rot, track.rest_t, cfg.deceleration)
        return TrackedState(track.object_id, t0, track.rest_position.copy(),
                            Rotation.from_matrix(track.rest_rotation).as_quat(), v0, w0, True, track.confidence,
                            f"push onset, seen {len(ts)} cloud(s) into it")

    def _state(self, track: PoseTrack, note: str = "") -> TrackedState:
        lin, ang = self._twist(track)
        return TrackedState(track.object_id, track.t, track.position.copy(), Rotation.from_matrix(track.rotation)
                            .as_quat(), lin, ang, track.moving, track.confidence, note)
