"""THE simulation core: one rigid object on a static plane, pybullet in DIRECT mode.

Used by dataset generation (`simulate_push`), by the physics baselines / planner (`simulate_from_state`) and by
the ROS sim node (`Simulator`). World: z up, plane z = 0, gravity -z. Physics runs at `SimConfig.physics_hz`
and states are recorded every DT = 1/15 s.

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
from typing import Iterator

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
class Simulator:
    """One pybullet DIRECT world holding a static plane and (at most) one object.

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
        self.body: int | None = None
        self.shape: Shape | None = None
        self.scale = np.ones(3)
        self.friction = config.friction
        self.mass = 0.0
        self.inertia = np.zeros((3, 3))  # object frame, about the origin (= COM)
        self.principal_moments = np.zeros(3)
        self._q_inertial = np.array([0.0, 0.0, 0.0, 1.0])  # object <- inertial (principal) frame
        self._r_inertial = Rotation.identity()  # the same as a scipy Rotation
        self._to_object = np.eye(4)  # q_world_object = _to_object @ q_world_inertial (see state())
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
        self.body = None

    def close(self) -> None:
        """Disconnect from pybullet (idempotent)."""
        if getattr(self, "client", None) is not None:
            try:
                self.client.disconnect()
            except Exception:  # noqa: BLE001 - already disconnected
                pass
            self.client = None
            self.body = None

    def __enter__(self) -> "Simulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

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
              friction: float | None = None, settle: bool = True) -> None:
        """Put `shape` (scaled per object axis) upright on the plane at `xy` with heading `yaw`, settled at rest.

        Replaces any previous object (the world is rebuilt). `friction` is the effective Coulomb coefficient
        (default: config.friction).
        """
        if self.client is None:
            raise RuntimeError("simulator is closed")
        scale = np.asarray(scale, dtype=np.float64).reshape(3)
        if np.any(~np.isfinite(scale)) or np.any(scale <= 0):
            raise ValueError(f"scale must be finite and positive, got {scale.tolist()}")
        mu = self.config.friction if friction is None else float(friction)
        if not 0 <= mu <= 10:
            raise ValueError(f"friction must be in [0, 10], got {mu}")
        self._reset_world()
        mp = shape.mass_properties(scale, self.config.density)
        self._set_body(shape, scale, mp, mu)
        z0 = -float((shape.vertices[:, 2] * scale[2]).min()) + self.config.spawn_clearance
        self.set_pose(np.array([xy[0], xy[1], z0]), yaw_quat(yaw))
        if settle:
            self._settle()

    def _set_body(self, shape: Shape, scale: np.ndarray, mp, mu: float) -> None:
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
        self.body = c.createMultiBody(baseMass=mp.mass, baseCollisionShapeIndex=cs,
                                      baseInertialFramePosition=[0, 0, 0],
                                      baseInertialFrameOrientation=q_in.tolist())
        c.changeDynamics(self.body, -1, mass=mp.mass, localInertiaDiagonal=moments.tolist(), lateralFriction=mu,
                         rollingFriction=cfg.rolling_friction, spinningFriction=cfg.spinning_friction,
                         restitution=cfg.restitution, linearDamping=cfg.linear_damping,
                         angularDamping=cfg.angular_damping,
                         activationState=self._p.ACTIVATION_STATE_DISABLE_SLEEPING)
        self.shape, self.scale, self.friction = shape, scale, mu
        self.mass, self.inertia, self.principal_moments, self._q_inertial = mp.mass, inertia, moments, q_in
        self._r_inertial = Rotation.from_quat(q_in)
        # q * q_in^-1 is linear in q: its 4x4 matrix, column j = e_j * q_in^-1 (scipy's product of the basis
        # quaternions). state() runs every frame: a matrix-vector product there costs ~8 us, a scipy Rotation
        # product ~80 us (its per-call overhead; the old hand-written product took ~12 us).
        inv = self._r_inertial.inv()
        self._to_object = np.stack([(Rotation.from_quat(e) * inv).as_quat() for e in np.eye(4)], axis=1)

    def _settle(self) -> None:
        cfg = self.config
        quiet = 0
        for _ in range(int(round(cfg.settle_time / DT))):
            self.step_frame()
            _, _, v, w = self.state()
            quiet = quiet + 1 if (np.linalg.norm(v) < cfg.rest_lin_vel * 0.2
                                  and np.linalg.norm(w) < cfg.rest_ang_vel * 0.2) else 0
            if quiet >= 2:
                break
        self.set_velocity(np.zeros(3), np.zeros(3))

    def remove(self) -> None:
        """Remove the object (the plane stays)."""
        if self.body is not None:
            self.client.removeBody(self.body)
            self.body = None
            self.shape = None

    def _require_body(self) -> int:
        if self.body is None:
            raise RuntimeError("no object in the simulator: call spawn() first")
        return self.body

    # -- state -----------------------------------------------------------------------------------------------
    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(pos (3,), quat xyzw (4,), lin_vel world (3,), ang_vel world (3,)) of the object frame."""
        b = self._require_body()
        pos, q_world_inertial = self.client.getBasePositionAndOrientation(b)
        lin, ang = self.client.getBaseVelocity(b)
        q = self._to_object @ np.asarray(q_world_inertial)
        q = q / np.linalg.norm(q)
        if q[3] < 0:  # canonical sign (w >= 0) for stable stored data
            q = -q
        return np.asarray(pos), q, np.asarray(lin), np.asarray(ang)

    def set_pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Teleport the object frame to `pos`, `quat` (x, y, z, w)."""
        b = self._require_body()
        q = Rotation.from_quat(np.asarray(quat, dtype=np.float64)) * self._r_inertial
        self.client.resetBasePositionAndOrientation(b, np.asarray(pos, dtype=np.float64).tolist(),
                                                    q.as_quat().tolist())

    def set_velocity(self, lin_world: np.ndarray, ang_world: np.ndarray) -> None:
        """Set the COM linear velocity and the angular velocity (world frame)."""
        self.client.resetBaseVelocity(self._require_body(), np.asarray(lin_world, float).tolist(),
                                      np.asarray(ang_world, float).tolist())

    def apply_impulse(self, impulse_world: np.ndarray, point_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply an instantaneous impulse (N s, world) at a world point: dv = J / m, dw = I_w^-1 (r x J).

        Contacts respond in the next physics step. Returns the new (lin_vel, ang_vel).
        """
        j = np.asarray(impulse_world, dtype=np.float64).reshape(3)
        pos, q, v, w = self.state()
        r = np.asarray(point_world, dtype=np.float64).reshape(3) - pos
        rot = quat_to_matrix(q)
        inertia_world = rot @ self.inertia @ rot.T
        v = v + j / self.mass
        w = w + np.linalg.solve(inertia_world, np.cross(r, j))
        self.set_velocity(v, w)
        return v, w

    def step_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance DT (config.substeps physics steps) and return the new state."""
        self._require_body()
        for _ in range(self.config.substeps):
            self.client.stepSimulation()
        return self.state()

    def ray_test(self, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """First hit of the segment start->end on the object: (point, normal) in the world, or None."""
        b = self._require_body()
        hit = self.client.rayTest(np.asarray(start, float).tolist(), np.asarray(end, float).tolist())[0]
        if hit[0] != b:
            return None
        return np.asarray(hit[3]), np.asarray(hit[4])

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """Tight world-frame bounds (min, max) of the object's scaled convex hull at its current pose.

        (pybullet's getAABB is looser: it bounds the rotated local box and adds the collision margin.)"""
        self._require_body()
        assert self.shape is not None  # set together with the body
        pos, q, _, _ = self.state()
        pts = (self.shape.hull()[0] * self.scale) @ quat_to_matrix(q).T + pos
        return pts.min(0), pts.max(0)
