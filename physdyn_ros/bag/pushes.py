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
"""Pushes recorded in a bag: the observed object states, the push starts, the object's cloud, the predictions.

numpy + rosbags only (no rclpy), so reports and datasets can be made on a machine without ROS.

Sources, all timed by their header stamps (the instant the data describes, not when it was recorded):
* object states: physdyn_ros/msg/ObjectState (the sim node, world-frame twist), nav_msgs/msg/Odometry (a
  tracker; its twist is in child_frame_id axes, as nav_msgs specifies, and is rotated into the table frame) or
  geometry_msgs/msg/PoseStamped (a pose tracker; velocities are then finite differences of the resampled poses).
  The pose must be the object's centre of mass (the dataset's object frame), in the table frame.
* push starts: geometry_msgs/msg/TwistStamped on `initial_twist` (the sim node publishes the velocities right
  after each push, stamped with frame 0). Without them a push starts where the object leaves rest
  (speed above `onset_speed` after `rest_frames` still frames), and frame 0's velocity is estimated.
* the object's points: sensor_msgs/msg/PointCloud2 (x, y, z float32) in the table frame; the latest cloud at or
  before the push (else the first one during it) is moved into the object frame with the state at its stamp.
* predictions: physdyn_ros/msg/PredictedTrajectory; a push takes the first one stamped within it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .. import geometry as geo
from ..conventions import DT, NUM_POINTS, REST_ANG_VEL, REST_FRAMES, REST_LIN_VEL
from ..perception.pointcloud2 import cloud_to_xyz
from .reading import open_bag
from .types import deserialize

NS = 1_000_000_000
DT_NS = int(round(DT * NS))

STATE_TYPES = ("physdyn_ros/msg/ObjectState", "nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
#: Default topic of each state type, in order of preference.
DEFAULT_STATE_TOPICS = {"object_state": STATE_TYPES[0], "odom": STATE_TYPES[1], "object_pose": STATE_TYPES[2]}


# --------------------------------------------------------------------------------------------------- containers
@dataclass
class States:
    """Observed states of the object, sorted by stamp. lin / ang are None when the source has no velocities."""

    t: np.ndarray  # (N,) int64 ns
    pos: np.ndarray  # (N, 3)
    quat: np.ndarray  # (N, 4) x, y, z, w; consecutive samples in the same hemisphere (for interpolation)
    lin: np.ndarray | None  # (N, 3) world frame
    ang: np.ndarray | None  # (N, 3) world frame
    topic: str
    msgtype: str

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass
class Cloud:
    t: int  # ns
    points: np.ndarray  # (M, 3) float64, table frame


@dataclass
class Prediction:
    received: int  # bag timestamp, ns
    t: int  # stamp of states[0], ns
    dt: float
    pos: np.ndarray  # (H+1, 3)
    quat: np.ndarray  # (H+1, 4)
    topple: np.ndarray  # (H+1,)
    model_id: str
    steps_in: int


@dataclass
class Session:
    """Everything a bag holds about pushes."""

    bag: Path
    states: States
    push_times: np.ndarray  # (P,) int64 ns, from initial_twist (empty when absent)
    push_twists: np.ndarray  # (P, 6) lin, ang world frame
    clouds: list[Cloud] = field(default_factory=list)
    predictions: list[Prediction] = field(default_factory=list)
    frame_id: str = ""


@dataclass
class Push:
    """One push: the observed states from its start to the next push (or the end of the recording)."""

    index: int
    t0: int  # ns, frame 0
    end: int  # ns, last instant that belongs to this push
    twist: np.ndarray | None  # (6,) velocities right after the push, if recorded
    cloud: Cloud | None
    prediction: Prediction | None
    rest: int | None = None  # ns of the first frame of rest (the object stays there until touched), None: never

    @property
    def settled(self) -> int:
        """The last instant the push's own motion is observed: its rest frame, else its end."""
        return self.rest if self.rest is not None else self.end


# ------------------------------------------------------------------------------------------------------ helpers
def _stamp(header) -> int:
    return int(header.stamp.sec) * NS + int(header.stamp.nanosec)


def _xyz(v) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


def _q(o) -> list[float]:
    return [float(o.x), float(o.y), float(o.z), float(o.w)]


def _continuous(quat: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions lie in the same hemisphere."""
    q = np.array(quat, dtype=np.float64)
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    return q


# ------------------------------------------------------------------------------------------------- the bag
def _find(conns: list, name: str | None, types: tuple[str, ...]) -> list:
    """Connections of topic `name` (exact, or a unique namespaced match of its last part) with one of `types`."""
    if name is None:
        return []
    full = name if name.startswith("/") else "/" + name
    hits = [c for c in conns if c.topic == full]
    if not hits and not name.startswith("/"):
        cands = {c.topic for c in conns if c.topic.rsplit("/", 1)[-1] == name}
        if len(cands) > 1:
            raise ValueError(f"topic {name!r} is ambiguous in the bag ({sorted(cands)}); give the full name")
        hits = [c for c in conns if c.topic in cands]
    bad = {c.msgtype for c in hits if c.msgtype not in types}
    if bad:
        raise ValueError(f"topic {hits[0].topic} has type {sorted(bad)}, expected one of {list(types)}")
    return hits


def load_session(bag: str | Path, state_topic: str | None = None, twist_topic: str | None = "initial_twist",
                 cloud_topic: str | None = "cloud", prediction_topic: str | None = "predicted_trajectory",
                 object_id: str | None = None) -> Session:
    """Read the pushes' raw material from a bag (folder or single .mcap/.db3 file). ValueError if unusable."""
    bag = Path(bag)
    with open_bag(bag) as reader:  # FileNotFoundError / BagError for a path that is not a readable bag
        conns = list(reader.connections)
        if state_topic is not None:
            state = _find(conns, state_topic, STATE_TYPES)
            if not state:
                raise ValueError(f"{bag}: no topic {state_topic!r}; it has {sorted({c.topic for c in conns})}")
        else:
            state = []
            for name in DEFAULT_STATE_TOPICS:
                state = [c for c in _find(conns, name, STATE_TYPES) if c.msgcount]
                if state:
                    break
            if not state:
                raise ValueError(f"{bag}: no object states found (looked for {', '.join(DEFAULT_STATE_TOPICS)}); "
                                 f"pass --state-topic (ObjectState, Odometry or PoseStamped of the object); the "
                                 f"bag has {sorted({c.topic for c in conns})}")
        twist = _find(conns, twist_topic, ("geometry_msgs/msg/TwistStamped",))
        cloud = _find(conns, cloud_topic, ("sensor_msgs/msg/PointCloud2",))
        pred = _find(conns, prediction_topic, ("physdyn_ros/msg/PredictedTrajectory",))
        msgtype = state[0].msgtype
        st: dict[str, list] = {"t": [], "pos": [], "quat": [], "lin": [], "ang": []}
        push_t, push_v, clouds, preds = [], [], [], []
        frame_id = ""
        for conn, received, data in reader.messages(connections=state + twist + cloud + pred):
            msg = deserialize(data, conn.msgtype)
            if conn in state:
                if conn.msgtype == STATE_TYPES[0]:
                    if object_id is not None and msg.object_id != object_id:
                        continue
                    pose, lin, ang = msg.pose, _xyz(msg.twist.linear), _xyz(msg.twist.angular)
                elif conn.msgtype == STATE_TYPES[1]:
                    if object_id is not None and msg.child_frame_id != object_id:
                        continue
                    pose = msg.pose.pose
                    q = np.array(_q(pose.orientation))
                    rot = geo.quat_to_matrix(q / np.linalg.norm(q))
                    lin = (rot @ np.array(_xyz(msg.twist.twist.linear))).tolist()  # child frame -> table frame
                    ang = (rot @ np.array(_xyz(msg.twist.twist.angular))).tolist()
                else:
                    pose, lin, ang = msg.pose, None, None
                frame_id = frame_id or msg.header.frame_id
                st["t"].append(_stamp(msg.header))
                st["pos"].append(_xyz(pose.position))
                st["quat"].append(_q(pose.orientation))
                st["lin"].append(lin)
                st["ang"].append(ang)
            elif conn in twist:
                push_t.append(_stamp(msg.header))
                push_v.append(_xyz(msg.twist.linear) + _xyz(msg.twist.angular))
            elif conn in cloud:
                pts = cloud_xyz(msg)
                if len(pts):
                    clouds.append(Cloud(_stamp(msg.header), pts))
            else:
                preds.append(prediction_arrays(msg, received))
    if not st["t"]:
        raise ValueError(f"{bag}: no object states on {state[0].topic}"
                         + (f" for object_id {object_id!r}" if object_id is not None else ""))
    order = np.argsort(np.asarray(st["t"], dtype=np.int64), kind="stable")
    t = np.asarray(st["t"], dtype=np.int64)[order]
    keep = np.concatenate([[True], np.diff(t) > 0])  # duplicate stamps (e.g. a republished state): keep the first
    idx = order[keep]
    quat = np.asarray(st["quat"], dtype=np.float64)[idx]
    norm = np.linalg.norm(quat, axis=1)
    if np.any(~np.isfinite(norm)) or np.any(norm < 1e-6):
        raise ValueError(f"{bag}: {state[0].topic} holds invalid orientations (zero or non-finite quaternions)")
    has_vel = st["lin"][0] is not None
    states = States(t=t[keep], pos=np.asarray(st["pos"], dtype=np.float64)[idx],
                    quat=_continuous(quat / norm[:, None]),
                    lin=np.asarray(st["lin"], dtype=np.float64)[idx] if has_vel else None,
                    ang=np.asarray(st["ang"], dtype=np.float64)[idx] if has_vel else None,
                    topic=state[0].topic, msgtype=msgtype)
    po = np.argsort(np.asarray(push_t, dtype=np.int64), kind="stable")
    return Session(bag=bag, states=states, push_times=np.asarray(push_t, dtype=np.int64)[po],
                   push_twists=np.asarray(push_v, dtype=np.float64).reshape(-1, 6)[po],
                   clouds=sorted(clouds, key=lambda c: c.t), predictions=sorted(preds, key=lambda p: p.received),
                   frame_id=frame_id)


def cloud_xyz(msg) -> np.ndarray:
    """(N, 3) float64 finite x, y, z of a (rosbags) PointCloud2, through the package's one cloud reader
    (physdyn_ros.perception.pointcloud2: fields read by name, any layout / endianness; ValueError naming the
    problem otherwise)."""
    return cloud_to_xyz(msg, skip_nans=True).astype(np.float64)


def prediction_arrays(msg, received: int) -> Prediction:
    n = len(msg.states)
    pos = np.array([_xyz(s.pose.position) for s in msg.states], dtype=np.float64).reshape(n, 3)
    quat = np.array([_q(s.pose.orientation) for s in msg.states], dtype=np.float64).reshape(n, 4)
    prob = np.array([float(s.topple_probability) for s in msg.states], dtype=np.float64)
    dt = int(msg.time_step.sec) + int(msg.time_step.nanosec) / NS
    return Prediction(received=int(received), t=_stamp(msg.header), dt=dt or DT, pos=pos, quat=quat,
                      topple=prob, model_id=str(msg.model_id), steps_in=int(msg.steps_in))


# ---------------------------------------------------------------------------------------------- resampling
def sample(states: States, times: np.ndarray) -> dict[str, np.ndarray]:
    """States at `times` (ns): linear interpolation of positions and velocities, slerp of orientations.

    Returns pos, quat (w >= 0), lin, ang (NaN where the source has no velocities) and `valid` (inside the
    recorded time range).
    """
    times = np.asarray(times, dtype=np.int64)
    t = states.t
    valid = (times >= t[0]) & (times <= t[-1])
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
    j = np.minimum(i + 1, len(t) - 1)
    span = (t[j] - t[i]).astype(np.float64)
    w = np.where(span > 0, (times - t[i]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)

    def lerp(a: np.ndarray) -> np.ndarray:
        return a[i] + (a[j] - a[i]) * w[:, None]

    if len(t) > 1:  # scipy's Slerp over the recorded orientations, at the times clamped to the recording (as lerp)
        slerp = Slerp((t - t[0]).astype(np.float64), Rotation.from_quat(states.quat))
        quat = slerp((np.clip(times, t[0], t[-1]) - t[0]).astype(np.float64)).as_quat()
    else:
        quat = Rotation.from_quat(np.repeat(states.quat[:1], len(times), axis=0)).as_quat()
    quat = np.where(quat[:, 3:4] < 0, -quat, quat)
    nan = np.full((len(times), 3), np.nan)
    return {"pos": lerp(states.pos), "quat": quat,
            "lin": lerp(states.lin) if states.lin is not None else nan,
            "ang": lerp(states.ang) if states.ang is not None else nan.copy(), "valid": valid}


def finite_difference_velocities(pos: np.ndarray, quat: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """World-frame linear and angular velocities of a pose sequence (central differences, one-sided at ends)."""
    n = len(pos)
    lin, ang = np.zeros((n, 3)), np.zeros((n, 3))
    if n < 2:
        return lin, ang
    lo = np.concatenate([[0], np.arange(n - 2), [n - 2]])
    hi = np.concatenate([[1], np.arange(2, n), [n - 1]])
    span = (hi - lo) * dt
    lin = (pos[hi] - pos[lo]) / span[:, None]
    rel = geo.quat_multiply(quat[hi], geo.quat_conjugate(quat[lo]))  # rotation from lo to hi, world frame
    ang = geo.quat_to_axis_angle(rel) / span[:, None]
    return lin, ang


# ------------------------------------------------------------------------------------------------- pushes
def find_pushes(session: Session, onset_speed: float = 0.05, onset_spin: float = 0.5,
                rest_lin_vel: float = REST_LIN_VEL, rest_ang_vel: float = REST_ANG_VEL,
                rest_frames: int = REST_FRAMES) -> list[Push]:
    """Split the session into pushes (see the module docstring); each knows when its object came to rest."""
    st = session.states
    if len(session.push_times):
        starts = [int(t) for t in session.push_times if st.t[0] <= t <= st.t[-1]]
        twists = [session.push_twists[k] for k, t in enumerate(session.push_times) if st.t[0] <= t <= st.t[-1]]
    else:
        starts, twists = _onsets(st, onset_speed, onset_spin, rest_frames), None
    pushes = []
    for k, t0 in enumerate(starts):
        end = starts[k + 1] - 1 if k + 1 < len(starts) else int(st.t[-1])
        pred = next((p for p in session.predictions if t0 - DT_NS // 2 <= p.t <= end), None)
        push = Push(index=k, t0=t0, end=end, twist=None if twists is None else np.asarray(twists[k]),
                    cloud=_pick_cloud(session.clouds, t0, end), prediction=pred)
        try:
            frames = _grid(session, push, int((end - t0) // DT_NS) + 1)
        except ValueError:
            frames = None
        if frames is not None:
            r = _rest_frame(frames["lin"], frames["ang"], rest_lin_vel, rest_ang_vel, rest_frames)
            push.rest = None if r is None else int(frames["t"][r])
        pushes.append(push)
    return pushes


def _grid(session: Session, push: Push, num_frames: int) -> dict[str, np.ndarray]:
    """The push's states at t0 + k * DT for the frames inside the push (at most num_frames)."""
    st = session.states
    times = push.t0 + np.round(np.arange(num_frames) * DT * NS).astype(np.int64)
    avail = int(np.sum(times <= push.end))
    if avail < 2:
        raise ValueError("fewer than 2 observed frames")
    s = sample(st, times[:avail])
    if not s["valid"].all():
        raise ValueError("the states do not cover the push")
    pos, quat = s["pos"], s["quat"]
    if st.lin is None:
        lin, ang = finite_difference_velocities(pos, quat, DT)
        if avail > 2:  # frame 0 is the still pose at the push: take the velocity of the first step instead
            lin[0], ang[0] = lin[1], ang[1]
    else:
        lin, ang = s["lin"], s["ang"]
    if push.twist is not None:  # exact velocities right after the push
        lin[0], ang[0] = push.twist[:3], push.twist[3:]
    return {"t": times[:avail], "pos": pos, "quat": quat, "lin": lin, "ang": ang}


def _rest_frame(lin: np.ndarray, ang: np.ndarray, rest_lin_vel: float, rest_ang_vel: float,
                rest_frames: int) -> int | None:
    """The simulator's rest rule: first frame r of a run of rest_frames still frames (None if none)."""
    quiet = 0
    for k in range(len(lin)):
        still = np.linalg.norm(lin[k]) < rest_lin_vel and np.linalg.norm(ang[k]) < rest_ang_vel
        quiet = quiet + 1 if still else 0
        if quiet >= rest_frames:
            return k - quiet + 1
    return None


def _onsets(st: States, onset_speed: float, onset_spin: float, rest_frames: int, min_steps: int = 2,
            min_travel: float = 0.005, min_turn: float = 0.05) -> list[int]:
    """Push starts of a recording without initial_twist: the last still sample before the object moves.

    Works on the recorded samples (any rate): a step between two samples moves if its speed exceeds
    onset_speed or its turn rate onset_spin. A push is a run of at least min_steps moving steps that travels
    min_travel metres or turns min_turn radians, after at least rest_frames * DT of stillness. A pose that jumps
    in one step (an object put back by hand, a respawn, a tracker glitch) is not a push.
    """
    dt = np.diff(st.t).astype(np.float64) / NS
    step = np.linalg.norm(np.diff(st.pos, axis=0), axis=1)
    turn = geo.quat_angle_between(st.quat[1:], st.quat[:-1])
    moving = (step / dt > onset_speed) | (turn / dt > onset_spin)
    out, still_since, k = [], int(st.t[0]), 0
    while k < len(moving):
        if not moving[k]:
            k += 1
            continue
        end = k
        while end < len(moving) and moving[end]:
            end += 1
        travel = np.linalg.norm(st.pos[end] - st.pos[k])
        rested = st.t[k] - still_since >= rest_frames * DT_NS
        turned = geo.quat_angle_between(st.quat[end], st.quat[k])
        if rested and end - k >= min_steps and (travel >= min_travel or turned >= min_turn):
            out.append(int(st.t[k]))
        still_since, k = int(st.t[end]), end
    return out


def _pick_cloud(clouds: list[Cloud], t0: int, end: int) -> Cloud | None:
    before = [c for c in clouds if c.t <= t0]
    if before:
        return before[-1]
    during = [c for c in clouds if t0 < c.t <= end]
    return during[0] if during else None


def push_frames(session: Session, push: Push, num_frames: int, rest_lin_vel: float = REST_LIN_VEL,
                rest_ang_vel: float = REST_ANG_VEL, rest_frames: int = REST_FRAMES) -> dict[str, Any]:
    """The push resampled at t0 + k * DT, k < num_frames, with the dataset's rest padding and topple labels.

    Raises ValueError (with the reason) when the recording does not cover the push until rest or num_frames.
    Returns pos, quat, lin_vel, ang_vel (float32), toppled (bool), length, topple_index (int32).
    """
    g = _grid(session, push, num_frames)
    pos, quat, lin, ang = g["pos"], g["quat"], g["lin"], g["ang"]
    avail = len(pos)
    r = _rest_frame(lin, ang, rest_lin_vel, rest_ang_vel, rest_frames)
    if r is None:
        if avail < num_frames:
            raise ValueError(f"the recording of this push ends after {avail} frames while the object still moves "
                             f"({'next push' if push.end < int(session.states.t[-1]) else 'end of the bag'}); "
                             f"{num_frames} frames or rest are needed")
        length = num_frames
    else:
        length = r + 1
    out = {"pos": np.zeros((num_frames, 3)), "quat": np.zeros((num_frames, 4)),
           "lin_vel": np.zeros((num_frames, 3)), "ang_vel": np.zeros((num_frames, 3))}
    n = min(length, avail)
    out["pos"][:n], out["quat"][:n], out["lin_vel"][:n], out["ang_vel"][:n] = pos[:n], quat[:n], lin[:n], ang[:n]
    out["pos"][n:], out["quat"][n:] = pos[n - 1], quat[n - 1]  # rest padding: rest pose, zero velocities
    toppled, topple_index = geo.topple_labels(out["quat"])
    res: dict[str, Any] = {k: v.astype(np.float32) for k, v in out.items()}  # arrays and numpy scalars
    res.update(toppled=toppled, length=np.int32(length), topple_index=np.int32(topple_index))
    return res


def object_points(session: Session, push: Push, num_points: int = NUM_POINTS, seed: int = 0) -> np.ndarray:
    """The push's cloud in the object frame (origin = centre of mass), `num_points` float32 rows.

    Clouds with more points are subsampled (fixed seed), smaller ones repeat points (the shape encoder
    max-pools, so duplicates change nothing). ValueError when the push has no cloud.
    """
    if push.cloud is None:
        raise ValueError("no cloud of the object at or after the push start")
    s = sample(session.states, np.array([push.cloud.t]))
    if not s["valid"][0]:
        raise ValueError("the cloud's stamp lies outside the recorded states")
    rot = geo.quat_to_matrix(s["quat"][0])
    pts = (push.cloud.points - s["pos"][0]) @ rot  # world -> object frame: R^T (p - c)
    m = len(pts)
    rng = np.random.default_rng(seed)
    if m > num_points:
        pts = pts[np.sort(rng.choice(m, num_points, replace=False))]
    elif m < num_points:
        pts = np.concatenate([pts, pts[rng.integers(0, m, num_points - m)]])
    return pts.astype(np.float32)
