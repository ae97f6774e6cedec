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
"""THE simulation core: rigid objects on a static plane, pybullet in DIRECT mode.

Used by dataset generation (`simulate_push`, one object per world), by the physics baselines / planner
(`simulate_from_state`) and by the ROS sim node (`Simulator`, several objects keyed by id in one world).
World: z up, plane z = 0, gravity -z. Physics runs at `SimConfig.physics_hz` and states are recorded every DT = 1/15 s.

Physics choices (all in `SimConfig`, so they are recorded in every dataset manifest):
* Friction: Bullet combines the lateral friction of two bodies as the PRODUCT, so the plane has friction 1.0
  and the object friction mu; the effective Coulomb coefficient is mu (checked by the stopping-distance test).
* Rolling / spinning friction 0: the objects are polyhedra touching the plane with multi-point contact
  manifolds, so lateral friction at the contacts already resists spinning and rolling; Bullet's extra
  rolling/spinning models are meant for single-point (sphere) contacts and would add a non-physical drag.
* Restitution 0 (Bullet's default, as the authors' earlier generator), no linear/angular damping (pybullet's
  default 0.04 damping would add a speed-proportional drag), sleeping disabled (our own rest test decides).
* Collision geometry: the exact convex hull for convex shapes; for concave shapes when `collision="auto"`, a
  compound of convex hulls: the shape's own convex pieces when it is built of them (`Shape.parts`: the
  families of shapes/families.py; exact and fast) or else a V-HACD convex decomposition (cached on disk; mug,
  trashcan, non-convex user meshes), both read by Bullet from one OBJ file with one object per piece;
  `collision="parts"` uses the pieces where a shape has them and the hull for every other shape (no V-HACD);
  `collision="hull"` uses the hull for everything (exact for a lone object on a plane: only hull points can
  touch a plane; only where the push ray meets the object differs, in the gaps of concave shapes).
  Bullet keeps a ~1 mm collision margin around hulls, so a resting object sits ~1 mm above the plane.
* Mass and inertia come from the true (scaled) geometry at a constant density. The inertia tensor of shapes
  that are not symmetric about their axes (a mug with its handle, tapered speakers) is not diagonal in the
  object frame: the body's inertial frame is put at the object origin (= COM) and rotated onto the principal
  axes (baseInertialFrameOrientation), with the principal moments as localInertiaDiagonal. pybullet reports
  and resets the pose of that inertial frame, so this class converts to and from the object frame.
"""
from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from ..conventions import DT, GRAVITY, REST_ANG_VEL, REST_FRAMES, REST_LIN_VEL
from ..data.format import atomic_path
from ..geometry import matrix_to_quat, quat_normalize, quat_to_matrix, up_tilt_angle, yaw_quat
from ..shapes.core import DEFAULT_DENSITY, Shape


@dataclass(frozen=True)
class SimConfig:
    """Physics constants of every simulation (documented in the module docstring)."""

    physics_hz: int = 240  # physics steps per second; a multiple of 15, >= 240
    gravity: float = GRAVITY  # m/s^2
    plane_friction: float = 1.0  # Bullet multiplies frictions: plane 1.0 -> effective = object friction
    friction: float = 0.5  # default effective lateral (Coulomb) friction coefficient
    rolling_friction: float = 0.0
    spinning_friction: float = 0.0
    restitution: float = 0.0
    linear_damping: float = 0.0
    angular_damping: float = 0.0
    density: float = DEFAULT_DENSITY  # kg/m^3, same for every object
    solver_iterations: int = 50  # pybullet's default, written down so datasets record it
    collision: str = "auto"  # "auto": hull if convex, else parts or V-HACD; "parts": no V-HACD; "hull": hull only
    vhacd_resolution: int = 200_000  # voxels of the V-HACD decomposition
    vhacd_cache_dir: str | None = None  # None: $PHYSDYN_CACHE or ~/.cache/physdyn_ros, + /vhacd
    spawn_clearance: float = 0.002  # m above the plane at spawn, then the object settles
    settle_time: float = 1.0  # s, at most, to let a spawned object come to rest
    rest_lin_vel: float = REST_LIN_VEL  # m/s: at rest below this speed ...
    rest_ang_vel: float = REST_ANG_VEL  # rad/s: ... and below this angular speed ...
    rest_frames: int = REST_FRAMES  # ... for this many consecutive recorded frames (0.27 s)

    def __post_init__(self) -> None:
        if self.physics_hz < 240 or self.physics_hz % 15:
            raise ValueError(f"physics_hz must be a multiple of 15 and >= 240, got {self.physics_hz}")
        if self.collision not in ("auto", "parts", "hull"):
            raise ValueError(f"collision must be 'auto', 'parts' or 'hull', got {self.collision!r}")
        if not 0 <= self.friction <= 10 or self.plane_friction <= 0:
            raise ValueError(f"friction must be in [0, 10], got {self.friction}")
        if self.density <= 0 or self.rest_frames < 1:
            raise ValueError("density must be positive and rest_frames >= 1")

    @property
    def substeps(self) -> int:
        return int(round(self.physics_hz * DT))

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------------- rotation helpers
# Rotations go through scipy.spatial.transform (geometry.py's wrappers); quat_to_matrix and yaw_quat stay importable
# from here.
def tilt_angle(quat: np.ndarray) -> np.ndarray:
    """Angle(s) between the object's up axis and world up, rad, for (..., 4) quaternions (x, y, z, w)."""
    return up_tilt_angle(quat_normalize(quat))


def _flush_c_stdout() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


@contextmanager
def quiet_stdout(stderr: bool = False) -> Iterator[None]:
    """Silence C-level stdout (and stderr) for the duration: pybullet's build-time line and connect banner,
    V-HACD's progress log. Python-level errors still propagate as exceptions."""
    streams = [sys.stdout] + ([sys.stderr] if stderr else [])
    try:
        fds = [s.fileno() for s in streams]
    except (AttributeError, OSError, ValueError):  # streams replaced (pytest capture, notebooks)
        yield
        return
    for s in streams:
        s.flush()
    saved = [os.dup(fd) for fd in fds]
    try:
        with open(os.devnull, "wb") as devnull:
            for fd in fds:
                os.dup2(devnull.fileno(), fd)
        yield
    finally:
        _flush_c_stdout()  # C stdio buffers (pipes are block-buffered) must drain into /dev/null
        for s, fd, old in zip(streams, fds, saved):
            s.flush()
            os.dup2(old, fd)
            os.close(old)


# ------------------------------------------------------------------------------------------ convex decomposition
def vhacd_cache_dir(config: SimConfig) -> Path:
    if config.vhacd_cache_dir:
        return Path(config.vhacd_cache_dir)
    base = os.environ.get("PHYSDYN_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "physdyn_ros")
    return Path(base) / "vhacd"


def _write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    with open(path, "w") as fh:
        fh.write("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in vertices))
        fh.write("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))


def _write_parts_obj(path: Path, parts: tuple[np.ndarray, ...]) -> None:
    """One OBJ object ("o part_i") per convex piece: Bullet makes a compound shape of the convex hulls of their
    vertices, as for a V-HACD result. Bullet collects a piece's vertices through its faces and takes their hull,
    so a fan of triangles that uses every vertex is enough (no hull computation here: no open3d in workers)."""
    lines, off = [], 0
    for i, part in enumerate(parts):
        v = np.asarray(part, dtype=np.float64)
        f = np.stack([np.zeros(len(v) - 2, dtype=int), np.arange(1, len(v) - 1), np.arange(2, len(v))], 1)
        lines.append(f"o part_{i}\n")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in v]
        lines += [f"f {a + 1 + off} {b + 1 + off} {c + 1 + off}\n" for a, b, c in f]
        off += len(v)
    path.write_text("".join(lines))


def convex_decomposition(shape: Shape, config: SimConfig = SimConfig()) -> Path:
    """OBJ file of the convex decomposition of `shape` (unscaled), computed once and cached on disk: its own
    convex pieces when it has them (`shape.parts`, milliseconds), else V-HACD's (seconds).

    The cache key is the geometry hash plus the V-HACD settings; files are written through the package's atomic
    writer (data.format.atomic_path: a temporary name, then a rename), so concurrent workers and interrupted runs
    never leave a truncated decomposition.
    """
    cache = vhacd_cache_dir(config)
    if shape.parts:
        out = cache / f"{hashlib.sha256(f'{shape.fingerprint()}:parts:v1'.encode()).hexdigest()[:32]}.obj"
        if out.is_file() and out.stat().st_size > 0:
            return out
        with atomic_path(out) as dst:
            _write_parts_obj(dst, shape.parts)
        return out

    with quiet_stdout(stderr=True):
        import pybullet

    key = hashlib.sha256(f"{shape.fingerprint()}:{config.vhacd_resolution}:v1".encode()).hexdigest()[:32]
    out = cache / f"{key}.obj"
    if out.is_file() and out.stat().st_size > 0:
        return out
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache, prefix=".vhacd-") as tmp, atomic_path(out) as dst:
        src, log = Path(tmp) / "in.obj", Path(tmp) / "log.txt"
        _write_obj(src, shape.vertices, shape.faces)
        with quiet_stdout():
            pybullet.vhacd(str(src), str(dst), str(log), resolution=int(config.vhacd_resolution))
        if not dst.is_file() or dst.stat().st_size == 0:
            raise RuntimeError(f"V-HACD failed for shape {shape.name}")
    return out


# ------------------------------------------------------------------------------------------------- the simulator
#: The id of the object of the single-object API (spawn without an object_id).
DEFAULT_ID = "object"
#: m: two objects whose collision shapes interpenetrate by more than this at spawn overlap (Bullet's ~1 mm hull
#: margins make touching objects read a fraction of a millimetre of penetration).
OVERLAP_TOLERANCE = 0.002


@dataclass
class Body:
    """One object in the world: its pybullet body and the physical properties derived from its geometry."""

    uid: int  # pybullet body unique id
    shape: Shape
    scale: np.ndarray
    friction: float
    mass: float
    inertia: np.ndarray  # object frame, about the origin (= COM)
    principal_moments: np.ndarray
    q_inertial: np.ndarray  # object <- inertial (principal) frame, x y z w
    r_inertial: Rotation  # the same as a scipy Rotation
    to_object: np.ndarray  # q_world_object = to_object @ q_world_inertial (see Simulator.state)
    collision: int = -1  # its pybullet collision shape (freed with the body: a long-running node spawns many)


class Simulator:
    """One pybullet DIRECT world holding a static plane and objects keyed by an id, all stepped together.

    Single-object use (data generation, re-simulation, the planner): `spawn(shape, ...)` without an object_id
    rebuilds the world with that one object (id DEFAULT_ID), and every method called without an object_id acts
    on the only object. Several objects (the sim node): `spawn(..., object_id=name)` adds a body to the current
    world, or replaces the body of that id, and refuses a pose that overlaps another object; methods then take the
    object_id, and step() / states() advance and read them all. Objects collide with each other; Bullet combines
    their frictions as the product (mu_a * mu_b against each other, mu against the plane).

    The object frame is the Shape's (origin = COM, z = up); every pose and velocity in and out is the object
    frame's, in the world frame: pos (3,), quat (x, y, z, w), linear and angular velocity (world).
    """

    def __init__(self, config: SimConfig = SimConfig()) -> None:
        with quiet_stdout(stderr=True):  # pybullet prints its build time on import and a banner on connect
            import pybullet
            from pybullet_utils import bullet_client

            self.client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.config = config
        self._p = pybullet
        self.bodies: dict[str, Body] = {}  # in spawn order
        self._reset_world()

    # -- world -----------------------------------------------------------------------------------------------
    def _reset_world(self) -> None:
        # A fresh world per object: results then depend only on the inputs, never on earlier simulations.
        c, cfg = self.client, self.config
        c.resetSimulation()
        c.setGravity(0, 0, -cfg.gravity)
        c.setPhysicsEngineParameter(fixedTimeStep=1.0 / cfg.physics_hz, numSubSteps=0,
                                    numSolverIterations=cfg.solver_iterations, deterministicOverlappingPairs=1)
        plane = c.createCollisionShape(self._p.GEOM_PLANE)
        self.plane = c.createMultiBody(0, plane)
        c.changeDynamics(self.plane, -1, lateralFriction=cfg.plane_friction, rollingFriction=0.0,
                         spinningFriction=0.0, restitution=1.0)  # restitution combines as a product too
        self.bodies = {}

    def close(self) -> None:
        """Disconnect from pybullet (idempotent)."""
        if getattr(self, "client", None) is not None:
            try:
                self.client.disconnect()
            except Exception:  # noqa: BLE001 - already disconnected
                pass
            self.client = None
            self.bodies = {}

    def __enter__(self) -> "Simulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

    # -- objects by id -----------------------------------------------------------------------------------------
    @property
    def ids(self) -> list[str]:
        """The ids of the objects in the world, in spawn order."""
        return list(self.bodies)

    def get(self, object_id: str | None = None) -> Body:
        """The object `object_id`, or (None) the only object; ValueError / RuntimeError naming what is there."""
        if object_id is not None:
            try:
                return self.bodies[object_id]
            except KeyError:
                known = ", ".join(repr(k) for k in self.bodies) or "none"
                raise ValueError(f"unknown object_id {object_id!r} (objects: {known})") from None
        if len(self.bodies) == 1:
            return next(iter(self.bodies.values()))
        if not self.bodies:
            raise RuntimeError("no object in the simulator: call spawn() first")
        raise RuntimeError(f"{len(self.bodies)} objects in the simulator ({', '.join(self.bodies)}): name one")

    def _of_sole(self, attr: str, empty: Any) -> Any:
        """`attr` of the only object (`empty` when there is none): what the single-object properties below read."""
        return getattr(self.get(), attr) if self.bodies else empty

    # The single-object API: the only object's properties (None / zeros when there is no object).
    @property
    def body(self) -> int | None:
        return self._of_sole("uid", None)

    @property
    def shape(self) -> Shape | None:
        return self._of_sole("shape", None)

    @property
    def scale(self) -> np.ndarray:
        return self._of_sole("scale", np.ones(3))

    @property
    def friction(self) -> float:
        return self._of_sole("friction", self.config.friction)

    @property
    def mass(self) -> float:
        return self._of_sole("mass", 0.0)

    @property
    def inertia(self) -> np.ndarray:
        return self._of_sole("inertia", np.zeros((3, 3)))

    @property
    def principal_moments(self) -> np.ndarray:
        return self._of_sole("principal_moments", np.zeros(3))

    @property
    def _q_inertial(self) -> np.ndarray:  # object <- inertial (principal) frame; read by tests
        return self._of_sole("q_inertial", np.array([0.0, 0.0, 0.0, 1.0]))

    # -- object ----------------------------------------------------------------------------------------------
    def _collision_shape(self, shape: Shape, scale: np.ndarray) -> int:
        c, p = self.client, self._p
        mode = self.config.collision
        if shape.convex or mode == "hull" or (mode == "parts" and not shape.parts):
            hv, _ = shape.hull()
            return c.createCollisionShape(p.GEOM_MESH, vertices=hv.tolist(), meshScale=scale.tolist())
        path = convex_decomposition(shape, self.config)
        return c.createCollisionShape(p.GEOM_MESH, fileName=str(path), meshScale=scale.tolist())

    def spawn(self, shape: Shape, scale=(1.0, 1.0, 1.0), xy=(0.0, 0.0), yaw: float = 0.0,
              friction: float | None = None, settle: bool = True, object_id: str | None = None) -> None:
        """Put `shape` (scaled per object axis) upright on the plane at `xy` with heading `yaw`, settled at rest.

        `object_id` None: the world is rebuilt with this one object (id DEFAULT_ID), so a simulation depends on
        its inputs only. `object_id` given: the object is added to the current world, replacing the object of
        that id; a pose that overlaps another object raises ValueError and leaves the world as it was. Settling
        steps the whole world. `friction` is the effective Coulomb coefficient with the plane (default:
        config.friction).
        """
        if self.client is None:
            raise RuntimeError("simulator is closed")
        scale = np.asarray(scale, dtype=np.float64).reshape(3)
        if np.any(~np.isfinite(scale)) or np.any(scale <= 0):
            raise ValueError(f"scale must be finite and positive, got {scale.tolist()}")
        mu = self.config.friction if friction is None else float(friction)
        if not 0 <= mu <= 10:
            raise ValueError(f"friction must be in [0, 10], got {mu}")
        if object_id is not None and (not isinstance(object_id, str) or not object_id):
            raise ValueError(f"object_id must be a non-empty string, got {object_id!r}")
        if object_id is None:
            self._reset_world()
            object_id = DEFAULT_ID
        mp = shape.mass_properties(scale, self.config.density)
        body = self._make_body(shape, scale, mp, mu)
        self._pose_body(body, self._upright_position(body, xy), yaw_quat(yaw))
        others = {k: b for k, b in self.bodies.items() if k != object_id}
        hits = self._overlaps(body, others) if others else {}
        if hits:
            self._drop(body)
            raise ValueError(f"{object_id!r} at ({float(xy[0]):.3f}, {float(xy[1]):.3f}) m would overlap "
                             + ", ".join(f"{k!r} (by {1e3 * d:.0f} mm)" for k, d in hits.items())
                             + ": spawn it elsewhere or move the other object first")
        old = self.bodies.pop(object_id, None)
        if old is not None:
            self._drop(old)
        self.bodies[object_id] = body
        if settle:
            self._settle(body)

    def _upright_position(self, body: Body, xy) -> np.ndarray:
        z0 = -float((body.shape.vertices[:, 2] * body.scale[2]).min()) + self.config.spawn_clearance
        return np.array([xy[0], xy[1], z0], dtype=np.float64)

    def place(self, object_id: str | None, xy, yaw: float = 0.0, settle: bool = True) -> None:
        """Teleport an object upright onto the plane at `xy`, heading `yaw`, at rest (settled unless not
        `settle`). No overlap test: see overlaps()."""
        body = self.get(object_id)
        self._pose_body(body, self._upright_position(body, xy), yaw_quat(yaw))
        self.client.resetBaseVelocity(body.uid, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        if settle:
            self._settle(body)

    def overlaps(self, object_id: str | None = None) -> dict[str, float]:
        """The objects that the object interpenetrates by more than OVERLAP_TOLERANCE: id -> depth, m."""
        body = self.get(object_id)
        return self._overlaps(body, {k: b for k, b in self.bodies.items() if b is not body})

    def _overlaps(self, body: Body, others: dict[str, Body]) -> dict[str, float]:
        out = {}
        for k, other in others.items():
            # closest points within 0 m: the contact points, with negative distances = penetration depths
            pts = self.client.getClosestPoints(body.uid, other.uid, 0.0)
            depth = max((-p[8] for p in pts), default=0.0)
            if depth > OVERLAP_TOLERANCE:
                out[k] = float(depth)
        return out

    def _make_body(self, shape: Shape, scale: np.ndarray, mp, mu: float) -> Body:
        c, cfg = self.client, self.config
        # Inertia about the object origin (the COM for Shapes; parallel-axis shift for clouds whose origin is
        # the given COM while the hull's centroid is elsewhere).
        d = -mp.com
        inertia = mp.inertia + mp.mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
        moments, axes = np.linalg.eigh(inertia)
        if np.linalg.det(axes) < 0:
            axes[:, 2] = -axes[:, 2]
        off = np.abs(inertia - np.diag(np.diag(inertia))).max()
        if off <= 1e-9 * np.trace(inertia):
            # Symmetric enough: keep the object axes (no frame conversion noise at all).
            moments, q_in = np.diag(inertia).copy(), np.array([0.0, 0.0, 0.0, 1.0])
        else:
            q_in = matrix_to_quat(axes)
        cs = self._collision_shape(shape, scale)
        uid = c.createMultiBody(baseMass=mp.mass, baseCollisionShapeIndex=cs, baseInertialFramePosition=[0, 0, 0],
                                baseInertialFrameOrientation=q_in.tolist())
        c.changeDynamics(uid, -1, mass=mp.mass, localInertiaDiagonal=moments.tolist(), lateralFriction=mu,
                         rollingFriction=cfg.rolling_friction, spinningFriction=cfg.spinning_friction,
                         restitution=cfg.restitution, linearDamping=cfg.linear_damping,
                         angularDamping=cfg.angular_damping,
                         activationState=self._p.ACTIVATION_STATE_DISABLE_SLEEPING)
        r_in = Rotation.from_quat(q_in)
        # q * q_in^-1 is linear in q: its 4x4 matrix, column j = e_j * q_in^-1 (scipy's product of the basis
        # quaternions). state() runs every frame: a matrix-vector product there costs ~8 us, a scipy Rotation
        # product ~80 us (its per-call overhead; the old hand-written product took ~12 us).
        inv = r_in.inv()
        to_object = np.stack([(Rotation.from_quat(e) * inv).as_quat() for e in np.eye(4)], axis=1)
        return Body(uid=uid, shape=shape, scale=scale, friction=mu, mass=mp.mass, inertia=inertia,
                    principal_moments=moments, q_inertial=q_in, r_inertial=r_in, to_object=to_object, collision=cs)

    def _drop(self, body: Body) -> None:
        """Remove a body and its collision shape from the world."""
        self.client.removeBody(body.uid)
        if body.collision >= 0:
            self.client.removeCollisionShape(body.collision)

    def _settle(self, body: Body) -> None:
        cfg = self.config
        quiet = 0
        for _ in range(int(round(cfg.settle_time / DT))):
            self.step()
            _, _, v, w = self._state(body)
            quiet = quiet + 1 if (np.linalg.norm(v) < cfg.rest_lin_vel * 0.2
                                  and np.linalg.norm(w) < cfg.rest_ang_vel * 0.2) else 0
            if quiet >= 2:
                break
        self.client.resetBaseVelocity(body.uid, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def remove(self, object_id: str | None = None) -> None:
        """Remove the object `object_id` (ValueError if unknown), or (None) every object; the plane stays."""
        if object_id is not None:
            self.get(object_id)
        for k in [object_id] if object_id is not None else list(self.bodies):
            self._drop(self.bodies.pop(k))

    def _require_body(self, object_id: str | None = None) -> int:
        return self.get(object_id).uid

    # -- state -----------------------------------------------------------------------------------------------
    def _state(self, b: Body) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pos, q_world_inertial = self.client.getBasePositionAndOrientation(b.uid)
        lin, ang = self.client.getBaseVelocity(b.uid)
        q = b.to_object @ np.asarray(q_world_inertial)
        q = q / np.linalg.norm(q)
        if q[3] < 0:  # canonical sign (w >= 0) for stable stored data
            q = -q
        return np.asarray(pos), q, np.asarray(lin), np.asarray(ang)

    def state(self, object_id: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(pos (3,), quat xyzw (4,), lin_vel world (3,), ang_vel world (3,)) of the object frame."""
        return self._state(self.get(object_id))

    def states(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """state() of every object, by id in spawn order."""
        return {k: self._state(b) for k, b in self.bodies.items()}

    def _pose_body(self, b: Body, pos: np.ndarray, quat: np.ndarray) -> None:
        q = Rotation.from_quat(np.asarray(quat, dtype=np.float64)) * b.r_inertial
        self.client.resetBasePositionAndOrientation(b.uid, np.asarray(pos, dtype=np.float64).tolist(),
                                                    q.as_quat().tolist())

    def set_pose(self, pos: np.ndarray, quat: np.ndarray, object_id: str | None = None) -> None:
        """Teleport the object frame to `pos`, `quat` (x, y, z, w)."""
        self._pose_body(self.get(object_id), pos, quat)

    def set_velocity(self, lin_world: np.ndarray, ang_world: np.ndarray, object_id: str | None = None) -> None:
        """Set the COM linear velocity and the angular velocity (world frame)."""
        self.client.resetBaseVelocity(self.get(object_id).uid, np.asarray(lin_world, float).tolist(),
                                      np.asarray(ang_world, float).tolist())

    def apply_impulse(self, impulse_world: np.ndarray, point_world: np.ndarray,
                      object_id: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Apply an instantaneous impulse (N s, world) at a world point: dv = J / m, dw = I_w^-1 (r x J).

        Contacts respond in the next physics step. Returns the new (lin_vel, ang_vel).
        """
        b = self.get(object_id)
        j = np.asarray(impulse_world, dtype=np.float64).reshape(3)
        pos, q, v, w = self._state(b)
        r = np.asarray(point_world, dtype=np.float64).reshape(3) - pos
        rot = quat_to_matrix(q)
        inertia_world = rot @ b.inertia @ rot.T
        v = v + j / b.mass
        w = w + np.linalg.solve(inertia_world, np.cross(r, j))
        self.client.resetBaseVelocity(b.uid, v.tolist(), w.tolist())
        return v, w

    def step(self) -> None:
        """Advance every object by DT (config.substeps physics steps)."""
        if self.client is None:
            raise RuntimeError("simulator is closed")
        for _ in range(self.config.substeps):
            self.client.stepSimulation()

    def step_frame(self, object_id: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance the world by DT (every object moves) and return the new state of the object."""
        b = self.get(object_id)  # refuse an unknown / ambiguous object before stepping
        self.step()
        return self._state(b)

    def ray_test(self, start: np.ndarray, end: np.ndarray,
                 object_id: str | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """First hit of the segment start->end on the object: (point, normal) in the world, or None (also when
        another object is hit first)."""
        b = self.get(object_id).uid
        hit = self.client.rayTest(np.asarray(start, float).tolist(), np.asarray(end, float).tolist())[0]
        if hit[0] != b:
            return None
        return np.asarray(hit[3]), np.asarray(hit[4])

    def aabb(self, object_id: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Tight world-frame bounds (min, max) of the object's scaled convex hull at its current pose.

        (pybullet's getAABB is looser: it bounds the rotated local box and adds the collision margin.)"""
        b = self.get(object_id)
        pos, q, _, _ = self._state(b)
        pts = (b.shape.hull()[0] * b.scale) @ quat_to_matrix(q).T + pos
        return pts.min(0), pts.max(0)
