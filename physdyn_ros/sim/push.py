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
"""Random pushes (dataset simulations) and re-simulation from a given state, recorded at DT = 1/15 s.

Recording rules (the dataset format's per-frame arrays):
* Frame 0 is the state right after the impulse; frames are DT apart; `num_frames` frames in all.
* Rest: the object is at rest once |v| < SimConfig.rest_lin_vel and |w| < rest_ang_vel for rest_frames
  consecutive frames; if that run starts at frame r, `length` = r + 1 and frames r+1.. are padding that repeat
  the pose of frame r with zero velocities. An object still moving at the last frame has length = num_frames
  (the simulation is cut at the maximum duration, (num_frames - 1) * DT).
* Toppled: True from the first frame whose tilt (angle between the object's up axis and world up) exceeds
  45 deg (conventions.TOPPLE_ANGLE) and stays True afterwards; topple_index is that frame or -1.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .. import geometry as geo
from ..shapes.core import Shape, shape_from_points
from .simulator import SimConfig, Simulator, quat_to_matrix

#: Default frames per simulation: 5 s at 15 Hz plus frame 0 (>= 61 frames are needed for 4 s roll-outs).
NUM_FRAMES: int = 76


@dataclass(frozen=True)
class PushConfig:
    """Distribution of the random push of one simulation (all documented, all stored in the manifest).

    The impulse is J = mass * speed * d: d is horizontal at a random azimuth, tilted by a random elevation.
    Slender objects topple whenever they slide fast (friction at the base tips them when mu h_com > half
    width), so gentle pushes dominate the speed distribution. It is applied where a ray along d hits the object's
    surface; the ray is offset from the COM sideways
    (fraction of the object's half width, gives spin) and vertically (uniform over the object's height, gives
    toppling / wobbling for high pushes). The speed is then capped so |v0| <= max_speed and |w0| <= max_spin.
    """

    speed: tuple[float, float] = (0.1, 3.2)  # m/s, COM speed the impulse would give a free body ...
    speed_power: float = 3.0  # ... drawn as lo + (hi - lo) * u**power, u ~ U(0, 1): many gentle pushes, some hard
    elevation_deg: tuple[float, float] = (-10.0, 10.0)  # impulse direction above the horizontal
    height: tuple[float, float] = (0.05, 0.7)  # ray height, fraction of the object's height above the plane
    lateral: tuple[float, float] = (-0.7, 0.7)  # ray offset, fraction of the half width across d
    max_speed: float = 3.5  # m/s cap on |v0|
    max_spin: float = 40.0  # rad/s cap on |w0|
    scale: tuple[float, float] = (0.5, 1.5)  # per-axis random scale of the shape, per simulation
    size_limits: tuple[float, float] = (0.04, 0.45)  # m, each scaled extent is clipped into this range
    friction: tuple[float, float] = (0.35, 0.65)  # effective friction range in varied-friction mode

    def to_dict(self) -> dict:
        return asdict(self)


def random_scale(shape: Shape, rng: np.random.Generator, push: PushConfig = PushConfig()) -> np.ndarray:
    """Per-axis scale U[scale] clipped so every scaled extent stays within push.size_limits."""
    s = rng.uniform(push.scale[0], push.scale[1], 3)
    ext = shape.extents
    return np.clip(s, push.size_limits[0] / ext, push.size_limits[1] / ext)


def _empty_record(num_frames: int) -> dict[str, np.ndarray]:
    return {"pos": np.zeros((num_frames, 3)), "quat": np.zeros((num_frames, 4)),
            "lin_vel": np.zeros((num_frames, 3)), "ang_vel": np.zeros((num_frames, 3))}


def record(sim: Simulator, num_frames: int = NUM_FRAMES) -> dict[str, Any]:
    """Record the spawned object from its current state (frame 0) for num_frames frames, with rest padding and
    topple labels (see the module docstring). Returns float32 / bool / int32 arrays of the dataset format."""
    if num_frames < 2:
        raise ValueError(f"num_frames must be >= 2, got {num_frames}")
    cfg = sim.config
    rec = _empty_record(num_frames)
    state = sim.state()
    quiet, length = 0, num_frames
    for t in range(num_frames):
        if t:
            state = sim.step_frame()
        for key, value in zip(("pos", "quat", "lin_vel", "ang_vel"), state):
            rec[key][t] = value
        still = np.linalg.norm(state[2]) < cfg.rest_lin_vel and np.linalg.norm(state[3]) < cfg.rest_ang_vel
        quiet = quiet + 1 if still else 0
        if quiet >= cfg.rest_frames:
            r = t - quiet + 1
            length = r + 1
            rec["pos"][r + 1:] = rec["pos"][r]
            rec["quat"][r + 1:] = rec["quat"][r]
            rec["lin_vel"][r + 1:] = 0.0
            rec["ang_vel"][r + 1:] = 0.0
            break
    toppled, topple_index = geo.topple_labels(rec["quat"])
    out: dict[str, Any] = {k: v.astype(np.float32) for k, v in rec.items()}  # arrays and numpy scalars
    out.update(toppled=toppled, length=np.int32(length), topple_index=np.int32(topple_index))
    return out


def sample_impulse(sim: Simulator, rng: np.random.Generator, push: PushConfig = PushConfig(),
                   max_tries: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """A random impulse (N s, world) and its application point on the spawned object's surface (world)."""
    pos, q, _, _ = sim.state()
    rot = quat_to_matrix(q)
    assert sim.shape is not None, "sample_impulse needs a spawned object"
    hull = (sim.shape.hull()[0] * sim.scale) @ rot.T + pos  # scaled hull in the world
    lo, hi = sim.aabb()
    height = hi[2] - max(lo[2], 0.0)
    reach = float(np.linalg.norm(hi[:2] - lo[:2])) + 0.1
    for _ in range(max_tries):
        az = rng.uniform(-np.pi, np.pi)
        el = np.radians(rng.uniform(*push.elevation_deg))
        d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        side = np.array([-np.sin(az), np.cos(az), 0.0])
        half_w = 0.5 * float(np.ptp(hull @ side))  # half width of the object across d
        z = max(lo[2], 0.0) + height * rng.uniform(*push.height)
        aim = np.array([pos[0], pos[1], z]) + side * half_w * rng.uniform(*push.lateral)
        hit = sim.ray_test(aim - d * reach, aim + d * reach)
        if hit is None or np.dot(hit[1], d) > -0.05:  # missed, or grazing a face almost parallel to d
            continue
        speed = push.speed[0] + (push.speed[1] - push.speed[0]) * rng.random() ** push.speed_power
        # Speed caps: scale the impulse down if the resulting free-body velocities exceed them.
        point = hit[0]
        inv_iw = np.linalg.inv(rot @ sim.inertia @ rot.T)
        unit = sim.mass * d
        w_per = float(np.linalg.norm(inv_iw @ np.cross(point - pos, unit)))
        speed = min(speed, push.max_speed, push.max_spin / max(w_per, 1e-9))
        return unit * speed, point
    # Fallback (tiny or odd objects): push horizontally through the COM.
    d = np.array([1.0, 0.0, 0.0])
    return sim.mass * rng.uniform(*push.speed) * d, pos.copy()


def simulate_push(sim: Simulator | None, shape: Shape, rng: np.random.Generator, push: PushConfig = PushConfig(),
                  friction: float | None = None, vary_friction: bool = False, num_frames: int = NUM_FRAMES,
                  config: SimConfig = SimConfig()) -> dict[str, Any]:
    """One dataset simulation: random scale and yaw, settled upright, a random impulse, recorded roll-out.

    `friction` None means config.friction, or U(push.friction) when `vary_friction`. `sim` None creates (and
    closes) a temporary Simulator with `config`. Returns the per-simulation arrays of the dataset format
    (pos, quat, lin_vel, ang_vel, toppled, length, topple_index, impulse, impulse_point, mass, inertia,
    friction, scale).
    """
    own = sim is None
    sim = Simulator(config) if sim is None else sim
    try:
        scale = random_scale(shape, rng, push)
        yaw = rng.uniform(-np.pi, np.pi)
        if friction is None:
            friction = rng.uniform(*push.friction) if vary_friction else sim.config.friction
        sim.spawn(shape, scale=scale, yaw=yaw, friction=friction)
        impulse, point = sample_impulse(sim, rng, push)
        sim.apply_impulse(impulse, point)
        out = record(sim, num_frames)
        out.update(impulse=impulse.astype(np.float32), impulse_point=point.astype(np.float32),
                   mass=np.float32(sim.mass), inertia=sim.principal_moments.astype(np.float32),
                   friction=np.float32(sim.friction), scale=scale.astype(np.float32))
        return out
    finally:
        if own:
            sim.close()


def simulate_from_state(shape_or_hull_points: Shape | np.ndarray, scale, pos, quat, lin_vel, ang_vel,
                        friction: float | None = None, num_frames: int = NUM_FRAMES,
                        config: SimConfig = SimConfig(), sim: Simulator | None = None) -> dict[str, Any]:
    """Re-simulate from a given initial state (frame 0) and record num_frames frames.

    `shape_or_hull_points` is a Shape or a raw (N, 3) point cloud in the object frame whose origin is the centre
    of mass (a dataset's canonical cloud); a cloud is simulated as its solid convex hull (mass and inertia of
    the hull at config.density, about the given origin). `scale` is applied per object axis; pos / quat
    (x, y, z, w) / velocities are world-frame object-frame state as stored in datasets. Returns pos, quat,
    lin_vel, ang_vel, toppled, length, topple_index, mass, inertia, friction, scale.
    """
    shape = shape_or_hull_points if isinstance(shape_or_hull_points, Shape) else \
        shape_from_points(np.asarray(shape_or_hull_points))
    own = sim is None
    sim = Simulator(config) if sim is None else sim
    try:
        sim.spawn(shape, scale=scale, friction=friction, settle=False)
        sim.set_pose(np.asarray(pos, float), np.asarray(quat, float))
        # one frame at rest at the pose first, then back to it: pybullet then holds the contacts an object lying
        # there has (a body teleported onto the table and launched at once meets it with none, and a fast tilting
        # push then topples where the same push of the settled object does not; test_sim_physics)
        sim.set_velocity(np.zeros(3), np.zeros(3))
        sim.step()
        sim.set_pose(np.asarray(pos, float), np.asarray(quat, float))
        sim.set_velocity(np.asarray(lin_vel, float), np.asarray(ang_vel, float))
        out = record(sim, num_frames)
        out.update(mass=np.float32(sim.mass), inertia=sim.principal_moments.astype(np.float32),
                   friction=np.float32(sim.friction), scale=np.asarray(sim.scale, np.float32))
        return out
    finally:
        if own:
            sim.close()
