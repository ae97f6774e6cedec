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
"""Simulated table: objects in pybullet (the same core as data generation), spawned and pushed through services.

Several objects, each under an id: the `object_id` and `objects` parameters' objects spawn at start,
`spawn_object` adds one (or replaces the one of that id, or removes it with category "remove"), `push` pushes the
one its object_id names; all share one world. Publishes every object's cloud on `cloud`, one true state per object
on `object_state` / `odom`, the current object's on `object_pose`, the pushed object's velocities right after a
push on `initial_twist`. During a push the pushed object's state is published every simulated frame, another's
while it moves, the resting ones at `rate`; the push ends when every object rests. Every pybullet call runs in the
node's default (mutually exclusive) callback group: pybullet clients are not thread-safe.

A managed (lifecycle) node (physdyn_ros/ros/lifecycle.py): the simulator and the start objects are made on
configure, closed on cleanup; it publishes and pushes only while active (services otherwise answer success=false
with the state); deactivating during a push holds the objects still. `autostart` configures and activates it.

The cloud is in the table frame, or (cloud_frame: camera) in the simulated camera's optical frame (REP 103: z
forward, x right, y down) named camera_frame, whose pose is published on /tf_static when tf2_msgs is importable
(a ROS 2 install) and logged at start as the perception node's sensor_frame / sensor_transform parameters.

Time: messages carry the simulation's time: the node clock while no push runs, t0 + k * DT for frame k of a push
(at real_time_factor 0 the stamps run ahead of the wall clock; publish_clock and use_sim_time share this clock).
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from ..conventions import DT, TABLE_FRAME
from ..msg import ObjectState
from ..perception.frames import RigidTransform, camera_optical_pose
from ..sim.table import (MAX_CONTACT_GAP, MAX_SPAWN_DISTANCE, check_size, check_spawn, object_at,
                         parse_object_entry, surface_gap)
from ..sim.camera import MAX_PIXELS as MAX_CAMERA_PIXELS, MIN_PIXELS as MIN_CAMERA_PIXELS, CameraSpec, DepthCamera
from ..sim.camera import points_differ
from ..ros.cloud import xyz_to_cloud
from ..ros.convert import ns_to_time, quat_to_matrix, tf_message, twist, vector3, xyz_to_numpy
from ..ros.diagnostics import OK, Diagnostics, RefusalWindow, Report
from ..ros.lifecycle import ManagedNode
from ..ros.params import declare
from ..ros.qos import CLOUD_QOS, LATCHED, STATE_QOS
from ..ros.run import run_node
from ..ros.trajectory import object_state
from ..srv import PushObject, SpawnObject

DT_NS = int(round(DT * 1e9))
CLOUD_FRAMES = ("table", "camera")
#: cloud_source values and collision values.
CLOUD_SOURCES = ("surface", "camera")
COLLISIONS = ("auto", "hull")
#: SpawnObject.category that removes the object named object_id instead of spawning one.
REMOVE = "remove"


@dataclass
class SimObject:
    """What the node keeps per object besides the simulator's body."""

    spawn_pose: tuple[float, float, float]  # x, y (m), yaw (rad): where reset puts it back
    cloud_obj: np.ndarray  # surface samples in the object frame (cloud_source surface)


class SimNode(ManagedNode):
    """Stand-in for the real table: spawn, push and watch simulated objects."""

    def __init__(self, **kwargs) -> None:
        super().__init__("sim", **kwargs)
        self.table_frame: str = declare(self, "table_frame", TABLE_FRAME,
                                        "fixed frame of the table (z up, plane z = 0); frame_id of every output",
                                        read_only=True)
        self.default_object_id: str = declare(self, "object_id", "object",
                                              "name of the object spawned at start (child_frame_id of odom); the "
                                              "id of a spawn_object request without one")
        declare(self, "category", "box", "shape category at start: box, cylinder, bottle, mug, trashcan, speaker "
                "or pybullet_data (out-of-category meshes)")
        declare(self, "shape_seed", 0, "which shape of the category (procedural / pybullet_data index)", low=0)
        declare(self, "mesh_path", "", "mesh file (OBJ/STL/PLY, metres, z up) to spawn at start instead of a "
                "category")
        declare(self, "scale", [1.0, 1.0, 1.0], "per-axis scale of the shape (object frame)", length=3, low=1e-3,
                high=100.0)
        declare(self, "spawn_pose", [0.0, 0.0, 0.0], "x (m), y (m), yaw (rad) of the object at spawn and reset",
                length=3, low=-MAX_SPAWN_DISTANCE, high=MAX_SPAWN_DISTANCE)
        declare(self, "objects", [""], "more objects spawned at start, one per entry: 'id=NAME category=C "
                "shape_seed=N mesh_path=P scale=SX,SY,SZ x=X y=Y yaw=YAW friction=MU' (only id is required; the "
                "others default to the parameters above and x = y = yaw = 0); empty entries are ignored")
        self.friction: float = declare(self, "friction", 0.5, "effective Coulomb friction coefficient with the "
                                       "table", low=0.0, high=10.0)
        declare(self, "collision", "auto", "collision geometry: 'auto' (hull for convex shapes, cached V-HACD "
                "decomposition otherwise) or 'hull' (convex hull for everything; faster first spawn); read on "
                "configure", read_only=True, choices=COLLISIONS)
        self.rate: float = declare(self, "rate", 15.0, "Hz at which the state is published while nothing moves "
                                   "(every simulated frame is published during a push)", read_only=True,
                                   low=0.1, high=1000.0)
        self.rtf: float = declare(self, "real_time_factor", 1.0, "simulated seconds per wall second during a "
                                  "push; 0 = as fast as possible", read_only=True, low=0.0, high=100.0)
        self.cloud_rate: float = declare(self, "publish_cloud_rate", 2.0, "Hz of the cloud topic; 0 = no cloud",
                                         read_only=True, low=0.0, high=100.0)
        declare(self, "cloud_source", "surface", "'surface': samples of the whole object surface posed by the "
                "current state; 'camera': partial view rendered by a simulated depth camera (pybullet "
                "TinyRenderer), object pixels only", choices=CLOUD_SOURCES)
        declare(self, "cloud_points", 1024, "points sampled on the surface (cloud_source surface)", low=16,
                high=10_000_000)
        declare(self, "cloud_noise", 0.0, "std dev of Gaussian noise added to each cloud point, m", low=0.0,
                high=0.1)
        declare(self, "camera_eye", [0.6, 0.0, 0.45], "camera position in the table frame, m (cloud_source "
                "camera)", length=3, low=-100.0, high=100.0, check=self._apart_from("camera_target"))
        declare(self, "camera_target", [0.0, 0.0, 0.05], "point the camera looks at, table frame, m", length=3,
                low=-100.0, high=100.0, check=self._apart_from("camera_eye"))
        declare(self, "camera_resolution", [320, 240], "rendered image width, height in pixels", length=2,
                low=MIN_CAMERA_PIXELS, high=MAX_CAMERA_PIXELS)
        declare(self, "camera_fov", 60.0, "vertical field of view, degrees", low=1.0, high=170.0)
        self.cloud_frame: str = declare(self, "cloud_frame", "table", "frame of the published cloud: 'table' "
                                        "(table_frame) or 'camera' (camera_frame, the simulated camera's optical "
                                        "frame at camera_eye looking at camera_target; its pose goes to "
                                        "/tf_static)", read_only=True, choices=CLOUD_FRAMES)
        self.camera_frame: str = declare(self, "camera_frame", "camera_optical_frame", "name of the camera's "
                                         "optical frame (z forward, x right, y down) for cloud_frame camera",
                                         read_only=True)
        declare(self, "max_push_time", 10.0, "s of simulated time after which a push ends even if the object "
                "still moves", low=DT, high=600.0)
        declare(self, "max_linear_speed", 10.0, "pushes giving a faster centre of mass are rejected, m/s", low=0.0)
        declare(self, "max_angular_speed", 100.0, "pushes giving a faster spin are rejected, rad/s", low=0.0)
        self.publish_clock: bool = declare(self, "publish_clock", False, "publish the simulation time on /clock",
                                           read_only=True)

        self.sim = None  # the pybullet Simulator: made on configure, closed on cleanup
        self.objects: dict[str, SimObject] = {}  # by id, in the simulator's (spawn) order
        self.object_id = self.default_object_id  # the current object: the last spawned or pushed
        self._rng = np.random.default_rng(0)
        # push bookkeeping (only touched from the sim group)
        self.push_id = 0
        self._running = False
        self._pushed = ""  # id of the object of the running push
        self._moving: set[str] = set()  # objects that moved in the last frame of the running push
        self._frame = 0
        self._t0_ns = 0
        self._wall0 = 0.0
        self._quiet = 0
        self._sim_ns = self.get_clock().now().nanoseconds
        self._wall_last = time.monotonic()

        self._group = self.default_callback_group  # pybullet and the lifecycle transitions: one at a time
        self._camera_pose: RigidTransform | None = None  # last pose sent on /tf_static
        self.pub_tf_static = self.pub_clock = None
        self.refused = 0
        self.last_error = ""
        self._refusals = RefusalWindow()
        self.diagnostics = Diagnostics(self, "simulation", self._diagnose, callback_group=self._group)
        self.start()  # autostart: configure + activate

    # -------------------------------------------------------------------------------------------- lifecycle
    def configure(self) -> None:
        if self.cloud_frame == "camera" and (not self.camera_frame or self.camera_frame == self.table_frame):
            raise ValueError(f"camera_frame must be a name other than table_frame, got {self.camera_frame!r}")
        from ..sim import SimConfig, Simulator  # pybullet is imported here, once per process

        self.sim = Simulator(SimConfig(collision=self.get_parameter("collision").value))
        self.camera = DepthCamera(self.sim)
        g = self._group
        self.pub_state = self.configured_publisher(ObjectState, "object_state", STATE_QOS)
        self.pub_odom = self.configured_publisher(Odometry, "odom", 50)
        self.pub_pose = self.configured_publisher(PoseStamped, "object_pose", 50)
        self.pub_twist = self.configured_publisher(TwistStamped, "initial_twist", 10)
        self.pub_cloud = self.configured_publisher(PointCloud2, "cloud", CLOUD_QOS)
        self.pub_clock = self.configured_publisher(Clock, "/clock", 10) if self.publish_clock else None
        self._camera_pose = None
        self.pub_tf_static = None
        if self.cloud_frame == "camera":
            try:
                from tf2_msgs.msg import TFMessage

                self.pub_tf_static = self.configured_publisher(TFMessage, "/tf_static", LATCHED)
            except ImportError:  # ROS from PyPI wheels has no tf2_msgs: the perception node takes a parameter
                pass
        # At real_time_factor 0 the step timer fires every millisecond and simulates a batch of frames per tick,
        # so services (reset, rejected pushes) are still answered between batches.
        step_period = 0.001 if self.rtf == 0 else DT / self.rtf / 2
        self._step_timer = self.configured_timer(step_period, self._on_step, callback_group=g)
        self._step_timer.cancel()

        p = self.get_parameter
        self.spawn(self.default_object_id, p("category").value, p("mesh_path").value, p("shape_seed").value,
                   p("scale").value, tuple(p("spawn_pose").value), self.friction)
        defaults = {"category": p("category").value, "shape_seed": p("shape_seed").value,
                    "mesh_path": p("mesh_path").value, "scale": p("scale").value, "x": 0.0, "y": 0.0, "yaw": 0.0,
                    "friction": self.friction}
        for entry in p("objects").value:
            if entry.strip():
                o = parse_object_entry(entry, defaults)
                self.spawn(o["id"], o["category"], o["mesh_path"], o["shape_seed"], o["scale"],
                           (o["x"], o["y"], o["yaw"]), o["friction"])
        self.object_id = self.default_object_id

        self.configured_service(PushObject, "push", self._on_push, callback_group=g)
        self.configured_service(Trigger, "reset", self._on_reset, callback_group=g)
        self.configured_service(SpawnObject, "spawn_object", self._on_spawn, callback_group=g)
        self.configured_timer(1.0 / self.rate, self._on_idle, callback_group=g)
        if self.cloud_rate > 0:
            self.configured_timer(1.0 / self.cloud_rate, self._on_cloud, callback_group=g)

    def activate(self) -> None:
        self._publish_states(self._idle_stamp())
        if self.cloud_frame == "camera":
            self._camera_pose = None  # sent (again) on /tf_static now that the publisher is enabled
            pose = self.camera_pose()
            self.get_logger().info(
                f"cloud in the camera frame '{self.camera_frame}': "
                + ("its pose is on /tf_static" if self.pub_tf_static is not None else
                   "tf2_msgs is not available, nothing is published on /tf_static")
                + f"; without tf2 give the perception node sensor_frame:={self.camera_frame} "
                f"sensor_transform:={[round(v, 6) for v in pose.as_list()]}")

    def describe(self) -> str:
        objects = ", ".join(f"{k} ({b.shape.name}, {b.mass:.3f} kg)" for k, b in self.sim.bodies.items())
        return f"{objects or 'no object'} in frame '{self.table_frame}', real_time_factor {self.rtf:g}"

    def deactivate(self) -> None:
        if self._running:
            self.get_logger().info(f"push {self.push_id} stopped by deactivate: the objects are held still")
            self._hold_still()

    def _hold_still(self) -> None:
        """End a running push and stop every object where it is."""
        self._end_push()
        for oid in self.sim.ids:
            self.sim.set_velocity(np.zeros(3), np.zeros(3), oid)

    def cleanup(self) -> None:
        self._running = False  # its timers are destroyed after this
        sim, self.sim = self.sim, None
        if sim is not None:
            sim.close()
        self.objects = {}
        self.pub_tf_static = self.pub_clock = None

    def destroy_node(self) -> None:
        if self.sim is not None:  # destroyed while configured: the pybullet client still goes
            self.sim.close()
        super().destroy_node()

    def _diagnose(self) -> Report:
        level = self._refusals.level(self.refused)
        if self.sim is None:
            return level, "no simulator (unconfigured)", {"object_id": self.object_id, "simulator": False,
                                                          "pushes": self.push_id, "refusals": self.refused,
                                                          "last_refusal": self.last_error}
        current = self.sim.bodies.get(self.object_id)
        return level, (f"last refusal: {self.last_error}" if level != OK else
                       "pushing" if self._running else "at rest"), {
            "object_id": self.object_id, "objects": ",".join(self.sim.ids), "simulator": True,
            "shape": current.shape.name if current else "", "mass_kg": f"{current.mass:.4f}" if current else "",
            "pushes": self.push_id, "push_running": self._running, "refusals": self.refused,
            "last_refusal": self.last_error, "real_time_factor": self.rtf}

    # ------------------------------------------------------------------------------------------------ objects
    def load_shape(self, category: str, mesh_path: str, shape_seed: int):
        """A Shape from a mesh file, a procedural category or a pybullet_data mesh; ValueError if impossible."""
        from ..shapes import resolve_shape

        return resolve_shape(category, shape_seed, mesh_path)

    def spawn(self, object_id: str, category: str, mesh_path: str, shape_seed: int, scale, spawn_pose,
              friction: float) -> None:
        """Add the object `object_id` (empty: the object_id parameter), or replace the object of that id; raises
        ValueError on bad input or a pose that overlaps another object (the objects are kept as they were then).
        A running push ends first and every object is held still."""
        scale, (x, y, yaw) = check_spawn(scale, spawn_pose, friction)
        shape = self.load_shape(category, mesh_path, shape_seed)
        check_size(shape, scale)
        oid = object_id or self.default_object_id
        self._hold_still()
        self.sim.spawn(shape, scale=scale, xy=(x, y), yaw=yaw, friction=friction, object_id=oid)
        self.camera.forget(oid)
        n = int(self.get_parameter("cloud_points").value)
        if n == len(shape.points):
            pts = shape.points.astype(np.float64)
        else:
            from ..shapes import sample_surface
            pts = sample_surface(shape.vertices, shape.faces, n, seed=0).astype(np.float64)
        self.objects.pop(oid, None)  # a replaced object moves to the end, as in the simulator
        self.objects[oid] = SimObject(spawn_pose=(x, y, yaw), cloud_obj=pts * scale)
        self.object_id = oid
        self._publish_states(self._idle_stamp())

    def remove(self, object_id: str) -> None:
        """Remove an object (ValueError naming the objects if there is none of that id)."""
        self.sim.get(object_id)  # refuse an unknown id before a running push is stopped
        self._hold_still()
        self.sim.remove(object_id)
        self.camera.forget(object_id)
        del self.objects[object_id]
        if self.object_id == object_id:
            self.object_id = self.sim.ids[-1] if self.sim.ids else self.default_object_id

    @property
    def spawn_pose(self) -> tuple[float, float, float]:
        """x (m), y (m), yaw (rad) where the current object was spawned (and reset puts it back)."""
        obj = self.objects.get(self.object_id)
        return obj.spawn_pose if obj is not None else (0.0, 0.0, 0.0)

    def half_extents(self, object_id: str | None = None) -> np.ndarray:
        """Half the object's (default: the current object's) scaled size along its axes, m."""
        b = self.sim.get(object_id or self.object_id)
        return 0.5 * b.shape.extents * b.scale

    # ------------------------------------------------------------------------------------------------- time
    def _idle_stamp(self) -> int:
        """Simulation time while nothing moves: follows the node clock, never goes backwards."""
        wall = time.monotonic()
        self._sim_ns = max(self.get_clock().now().nanoseconds,
                           self._sim_ns + int((wall - self._wall_last) * 1e9))
        self._wall_last = wall
        return self._sim_ns

    # ----------------------------------------------------------------------------------------------- outputs
    def _publish_states(self, stamp_ns: int, ids=None) -> None:
        """object_state and odom of the objects `ids` (default: all), object_pose of the current one."""
        stamp = ns_to_time(stamp_ns)
        header = Header(frame_id=self.table_frame, stamp=stamp)
        for oid in self.sim.ids if ids is None else ids:
            pos, q, v, w = self.sim.state(oid)
            msg = object_state(self.table_frame, stamp, oid, pos, q, v, w)
            self.pub_state.publish(msg)
            if oid == self.object_id:
                self.pub_pose.publish(PoseStamped(header=header, pose=msg.pose))
            # nav_msgs/Odometry: the twist is expressed in child_frame_id (the object's own axes).
            rot = quat_to_matrix(q)
            odom = Odometry(header=header, child_frame_id=oid)
            odom.pose.pose = msg.pose
            odom.twist.twist = twist(rot.T @ v, rot.T @ w)
            self.pub_odom.publish(odom)
        if self.pub_clock is not None:
            self.pub_clock.publish(Clock(clock=stamp))

    def current_cloud(self) -> np.ndarray:
        """The cloud the sensor would see now (every object), table frame, (N, 3)."""
        if self.get_parameter("cloud_source").value == "camera":
            pts = self.camera.render(self.camera_spec())
        else:
            posed = []
            for oid, (pos, q, _, _) in self.sim.states().items():
                posed.append(self.objects[oid].cloud_obj @ quat_to_matrix(q).T + pos)
            pts = np.concatenate(posed) if posed else np.zeros((0, 3))
        noise = float(self.get_parameter("cloud_noise").value)
        if noise > 0 and len(pts):
            pts = pts + self._rng.normal(0.0, noise, pts.shape)
        return pts

    def camera_spec(self) -> CameraSpec:
        """The simulated camera as its parameters set it now."""
        p = self.get_parameter
        return CameraSpec.make(p("camera_eye").value, p("camera_target").value, p("camera_resolution").value,
                               p("camera_fov").value)

    def _apart_from(self, other: str):
        """A parameter check: camera_eye and camera_target must differ (the camera looks from one to the other)."""
        return lambda value: points_differ(value, self.get_parameter(other).value if self.has_parameter(other)
                                           else None, other)

    def camera_pose(self) -> RigidTransform:
        """Pose of camera_frame in the table frame (maps optical-frame points into the table frame) from the
        current camera_eye / camera_target; published on /tf_static whenever it changes."""
        p = self.get_parameter
        pose = camera_optical_pose(p("camera_eye").value, p("camera_target").value)
        if self.pub_tf_static is not None and (self._camera_pose is None or not (
                np.allclose(pose.rotation, self._camera_pose.rotation)
                and np.allclose(pose.translation, self._camera_pose.translation))):
            self.pub_tf_static.publish(tf_message(pose.as_list(), self.table_frame, self.camera_frame,
                                                  self.get_clock().now().to_msg()))
        self._camera_pose = pose
        return pose

    def _on_cloud(self) -> None:
        stamp_ns = self._sim_ns if self._running else self._idle_stamp()
        try:  # the parameters are checked when set; this catches what only rendering finds
            pts, frame = self.current_cloud(), self.table_frame
            if self.cloud_frame == "camera":
                pose = self.camera_pose()
                pts, frame = pose.inverse().apply(np.asarray(pts, dtype=np.float64)), self.camera_frame
        except ValueError as exc:
            self.get_logger().warning(f"no cloud: {exc}", throttle_duration_sec=5.0)
            return
        self.pub_cloud.publish(xyz_to_cloud(pts, frame, ns_to_time(stamp_ns)))

    def _on_idle(self) -> None:
        if not self._running:
            self._publish_states(self._idle_stamp())
        else:  # the objects at rest during a push (the moving ones are published every frame)
            resting = [k for k in self.sim.ids if k != self._pushed and k not in self._moving]
            if resting:
                self._publish_states(self._sim_ns, resting)

    # ------------------------------------------------------------------------------------------------ pushes
    def start_push(self, req: PushObject.Request) -> tuple[bool, str]:
        """Apply a push; on success frame 0 and initial_twist are published. Returns (ok, message)."""
        if self._running:
            return False, (f"push rejected: push {self.push_id} is still running (the object moves); wait until "
                           "it comes to rest or call reset")
        # no id: the object at the contact point (a robot pushing by perception's ids knows no sim ids)
        oid = req.object_id or (self.object_id if req.use_velocity else object_at(self.sim, xyz_to_numpy(req.point),
                                                                                  self.object_id))
        if oid not in self.sim.bodies:
            known = ", ".join(repr(k) for k in self.sim.ids) or "none: spawn one"
            return False, f"push rejected: unknown object_id {oid!r} (objects: {known})"
        vmax = float(self.get_parameter("max_linear_speed").value)
        wmax = float(self.get_parameter("max_angular_speed").value)
        body = self.sim.get(oid)
        pos, q, v_before, w_before = self.sim.state(oid)
        if req.use_velocity:
            lin, ang = xyz_to_numpy(req.velocity.linear), xyz_to_numpy(req.velocity.angular)
            if not (np.all(np.isfinite(lin)) and np.all(np.isfinite(ang))):
                return False, "push rejected: velocity is not finite"
            if not (np.any(lin) or np.any(ang)):
                return False, "push rejected: the velocity is zero (use_velocity sets it; give a non-zero one)"
            if np.linalg.norm(lin) > vmax or np.linalg.norm(ang) > wmax:
                return False, (f"push rejected: velocity |v| = {np.linalg.norm(lin):.3g} m/s, |w| = "
                               f"{np.linalg.norm(ang):.3g} rad/s exceeds max_linear_speed {vmax:g} / "
                               f"max_angular_speed {wmax:g}")
            self.sim.set_velocity(lin, ang, oid)
        else:
            impulse, point = xyz_to_numpy(req.impulse), xyz_to_numpy(req.point)
            if not (np.all(np.isfinite(impulse)) and np.all(np.isfinite(point))):
                return False, "push rejected: impulse or point is not finite"
            if not np.any(impulse):
                return False, "push rejected: the impulse is zero"
            if not np.any(point):
                point = pos
            gap = surface_gap(self.sim, oid, point)
            if gap > MAX_CONTACT_GAP:
                return False, (f"push rejected: point {[round(v, 4) for v in point.tolist()]} is {gap:.3f} m outside "
                               f"the surface of {oid!r} (at most {MAX_CONTACT_GAP:g} m: the point is where the "
                               "pusher touches the object)")
            lin, ang = self.sim.apply_impulse(impulse, point, oid)
            if np.linalg.norm(lin) > vmax or np.linalg.norm(ang) > wmax:
                self.sim.set_velocity(v_before, w_before, oid)
                return False, (f"push rejected: the impulse would give |v| = {np.linalg.norm(lin):.3g} m/s, |w| = "
                               f"{np.linalg.norm(ang):.3g} rad/s (mass {body.mass:.3g} kg), above "
                               f"max_linear_speed {vmax:g} / max_angular_speed {wmax:g}")
        # Frame 0 = the state right after the push (the dataset convention: velocities set, pose unchanged).
        self.push_id += 1
        self.object_id, self._pushed, self._moving = oid, oid, {oid}
        self._running, self._frame, self._quiet = True, 0, 0
        self._t0_ns = self._idle_stamp() + 1  # strictly after every idle stamp already published
        self._sim_ns = self._t0_ns
        self._wall0 = time.monotonic()
        self._publish_states(self._t0_ns)  # every object at the push instant
        _, _, v, w = self.sim.state(oid)
        self.pub_twist.publish(TwistStamped(header=Header(frame_id=self.table_frame, stamp=ns_to_time(self._t0_ns)),
                                            twist=twist(v, w)))
        self._step_timer.reset()
        return True, f"push {self.push_id} of {oid!r} started"

    def _on_push(self, req: PushObject.Request, res: PushObject.Response) -> PushObject.Response:
        try:
            res.success, res.message = self.start_push(req)
        except Exception as exc:  # noqa: BLE001 - a bad request must never take the node down
            res.success, res.message = False, f"push failed: {exc}"
        if res.success:
            _, _, v, w = self.sim.state(self._pushed)
            res.push_id = self.push_id
            res.initial_twist = twist(v, w)
        else:
            self._refuse(res.message)
        return res

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self.last_error = reason
        self.get_logger().warning(reason)

    def _on_step(self) -> None:
        if not self._running:
            self._step_timer.cancel()
            return
        if self.rtf == 0:
            frames = 8
        else:  # catch up with the wall clock (bounded, so a stalled process does not freeze the executor)
            due = int((time.monotonic() - self._wall0) * self.rtf / DT)
            frames = min(max(0, due - self._frame), 8)
        cfg = self.sim.config
        max_frames = int(round(float(self.get_parameter("max_push_time").value) / DT))
        for _ in range(frames):
            self.sim.step()  # every object: the pushed one may hit others
            self._frame += 1
            self._sim_ns = self._t0_ns + self._frame * DT_NS
            moving = {k for k, (_, _, v, w) in self.sim.states().items()
                      if np.linalg.norm(v) >= cfg.rest_lin_vel or np.linalg.norm(w) >= cfg.rest_ang_vel}
            self._quiet = 0 if moving else self._quiet + 1
            at_rest = self._quiet >= cfg.rest_frames
            if at_rest:
                for oid in self.sim.ids:  # settled: hold them exactly still
                    self.sim.set_velocity(np.zeros(3), np.zeros(3), oid)
            # the pushed object every frame, the others while they move and once when they stop
            shown = moving | self._moving | {self._pushed}
            self._moving = moving
            self._publish_states(self._sim_ns, None if at_rest else [k for k in self.sim.ids if k in shown])
            if at_rest or self._frame >= max_frames:
                self.get_logger().info(f"push {self.push_id} ended after {self._frame * DT:.2f} s "
                                       f"({'at rest' if at_rest else 'max_push_time'})")
                self._end_push()
                return

    def _end_push(self) -> None:
        if self._running:
            self._running = False
            self._wall_last = time.monotonic()
        self._step_timer.cancel()

    # ---------------------------------------------------------------------------------------------- services
    def _on_reset(self, req: Trigger.Request, res: Trigger.Response) -> Trigger.Response:
        try:
            res.success, res.message = self.reset()
        except Exception as exc:  # noqa: BLE001
            res.success, res.message = False, f"reset failed: {exc}"
        if not res.success:
            self._refuse(res.message)
        return res

    def reset(self) -> tuple[bool, str]:
        """Every object back at its spawn pose, at rest; refused (nothing moves) when two spawn poses overlap
        (an object was spawned where another had been pushed away from)."""
        self._hold_still()
        before = {k: self.sim.state(k)[:2] for k in self.sim.ids}
        for k, obj in self.objects.items():
            self.sim.place(k, obj.spawn_pose[:2], obj.spawn_pose[2], settle=False)
        clash = next(((k, hits) for k in self.sim.ids if (hits := self.sim.overlaps(k))), None)
        if clash is not None:
            for k, (pos, q) in before.items():
                self.sim.set_pose(pos, q, k)
            return False, (f"reset refused: the spawn poses of {clash[0]!r} and {sorted(clash[1])[0]!r} overlap; "
                           "spawn one of them again elsewhere (spawn_object with its id)")
        for k, obj in self.objects.items():
            self.sim.place(k, obj.spawn_pose[:2], obj.spawn_pose[2])
        self._hold_still()
        self._publish_states(self._idle_stamp())
        where = ", ".join(f"{k} at ({o.spawn_pose[0]:g}, {o.spawn_pose[1]:g}, yaw {o.spawn_pose[2]:g})"
                          for k, o in self.objects.items())
        return True, f"{where or 'no object'}: back at rest"

    def _on_spawn(self, req: SpawnObject.Request, res: SpawnObject.Response) -> SpawnObject.Response:
        if req.category == REMOVE:
            oid = req.object_id or self.default_object_id
            try:
                self.remove(oid)
            except ValueError as exc:
                res.success, res.message = False, f"remove failed: {exc}"
                self._refuse(res.message)
                return res
            self._publish_states(self._idle_stamp())
            res.success, res.message = True, f"removed {oid} ({len(self.objects)} objects left)"
            self.get_logger().info(res.message)
            return res
        scale = xyz_to_numpy(req.scale)
        if not np.any(scale):
            scale = np.ones(3)
        friction = req.friction if req.friction != 0.0 else float(self.get_parameter("friction").value)
        category = req.category or self.get_parameter("category").value
        try:
            self.spawn(req.object_id, category, req.mesh_path, req.shape_seed, scale, (req.x, req.y, req.yaw),
                       friction)
        except Exception as exc:  # noqa: BLE001 - bad mesh, unknown category, overlap: answer, keep the objects
            res.success, res.message = False, f"spawn failed: {exc}"
            self._refuse(res.message)
            return res
        body = self.sim.get(self.object_id)
        res.success = True
        res.message = (f"spawned {self.object_id}: {body.shape.name} ({body.mass:.3f} kg); "
                       f"{len(self.objects)} objects")
        res.half_extents = vector3(self.half_extents())
        res.mass = float(body.mass)
        self.get_logger().info(res.message)
        return res


def main(args: list[str] | None = None) -> int:
    return run_node(SimNode, "sim", args)


if __name__ == "__main__":
    sys.exit(main())
