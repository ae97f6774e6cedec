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
"""Perception: a table-top point cloud -> one learned shape feature (ShapeFeature) per object on the table.

A thin ROS adapter over physdyn_ros.perception (the ROS-free core):
1. the cloud's frame: the table frame as is; `sensor_frame` with the static `sensor_transform` parameter; any
   other frame through tf2 when tf2_ros can be imported (a full ROS 2 install) and `use_tf` is on; otherwise the
   cloud is refused with the reason;
2. x, y, z read from the message (a random subset of `max_points` for larger clouds), then
   perception.segment: table plane, clusters, per-object outlier removal (see physdyn_ros/perception/scene.py);
3. ids: `single_object` (default) publishes one feature, of the object tracked under `object_id` (the largest
   when it is first seen or lost), as this node always did; otherwise one feature per object with the ids of
   perception.Tracker (`<id_prefix><n>`, stable while objects move);
4. Predictor.encode per object; features stamped with the cloud's stamp in the table frame; outlines on
   `object_markers`;
5. with `track_poses`: each tracked object's pose and twist from the clouds themselves (perception.PoseTracker:
   its points registered to its reference) on `tracked_state`, one ObjectState per object per cloud stamped with
   the cloud's stamp; a push (an object at rest starts to move) gives, once, its state at the estimated onset
   instant with the twist right after it on `initial_state`. Clouds or objects it skips say why on /diagnostics.

A managed (lifecycle) node, see physdyn_ros/ros/lifecycle.py: the encoder (the model), the tf listener and the
publishers are made on configure and released on cleanup; the cloud subscription exists only while active (clouds
are not processed otherwise). With `autostart` (default) it configures and activates itself at start.
"""
from __future__ import annotations

import math
import sys
import time
import zlib

import numpy as np
from geometry_msgs.msg import Point
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..conventions import TABLE_FRAME
from ..msg import ObjectState, ShapeFeature
from ..perception import RigidTransform, SceneConfig, Tracker, outline_xy, parse_transform, segment
from ..perception.pose_tracking import COM_SOURCES, PoseConfig, PoseTracker, TrackedState, footprint_com
from ..perception.scene import Preprocess, preprocess  # noqa: F401 - re-exported (bench/bench_nodes.py)
from ..perception.scene import Scene, random_rows
from ..perception.tracking import shape_signature
from ..ros.cloud import cloud_size, cloud_to_xyz, xyz_to_cloud
from ..ros.convert import ns_to_time, point, time_to_ns, vector3
from ..ros.model import load_predictor
from ..ros.params import declare
from ..ros.run import run_node
from ..ros.diagnostics import OK, Diagnostics, RefusalWindow, Report
from ..ros.lifecycle import ManagedNode
from ..ros.qos import CLOUD_SENSOR_QOS, FEATURE_QOS, LATCHED, STATE_QOS
from ..ros.throttle import ReasonThrottle
from ..ros.trajectory import object_state

#: Outline colours, picked by the object id (the same id keeps its colour).
PALETTE = [(0.90, 0.10, 0.10), (0.10, 0.60, 0.90), (0.20, 0.75, 0.20), (0.95, 0.60, 0.05), (0.60, 0.25, 0.85),
           (0.05, 0.75, 0.70), (0.85, 0.30, 0.60), (0.55, 0.55, 0.10)]


def tf2_available() -> bool:
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        return False
    return True


def _transform_check(values) -> str | None:
    """Parameter check of sensor_transform: 7 finite numbers with a non-zero quaternion."""
    try:
        parse_transform(values)
    except ValueError as exc:
        return f"is not a pose: {exc}"
    return None


class PerceptionNode(ManagedNode):
    """Subscribes `cloud`; publishes `shape_feature` (one per object), `object_markers`, `tracked_state` and
    `initial_state`."""

    def __init__(self, **kwargs) -> None:
        super().__init__("perception", **kwargs)
        declare(self, "model_path", "", "checkpoint, loaded on configure (cleanup, set, configure: another model); "
                "empty = the shipped default model")
        declare(self, "device", "cpu", "torch device for the encoder (read on configure)")
        declare(self, "num_threads", 1, "torch intra-op threads (set explicitly: no oversubscription; read on "
                "configure)", low=1, high=256)
        self.table_frame: str = declare(self, "table_frame", TABLE_FRAME, "fixed frame of the table (z up, plane "
                                        "z = 0); clouds are transformed into it and features published in it",
                                        read_only=True)
        declare(self, "sensor_frame", "", "a cloud frame whose pose in table_frame is the static sensor_transform "
                "(used instead of tf for that frame); empty = none")
        declare(self, "sensor_transform", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "pose of sensor_frame in "
                "table_frame: x, y, z (m), qx, qy, qz, qw (as static_transform_publisher takes it)", length=7,
                check=_transform_check)
        declare(self, "use_tf", True, "look up other frames with tf2 when tf2_ros can be imported (read on "
                "configure)", read_only=True)
        declare(self, "tf_timeout", 0.05, "s to wait for a tf transform at the cloud's stamp", low=0.0, high=5.0)
        declare(self, "single_object", True, "true: one feature per cloud, for the object tracked as object_id "
                "(the largest when first seen or lost); false: one feature per object, ids <id_prefix><n>")
        declare(self, "object_id", "object", "object_id of the feature in single_object mode")
        declare(self, "id_prefix", "object_", "ids of tracked objects (single_object false): <id_prefix><n>")
        declare(self, "track_gate", 0.1, "m, largest distance between an object's predicted and measured centroid "
                "for it to keep its id", low=0.001, high=10.0)
        declare(self, "track_timeout", 2.0, "s (cloud stamps) after which an unseen object is lost: its id then "
                "goes only to an object of its shape within 0.5 m", low=0.0, high=3600.0)
        declare(self, "track_memory", 30.0, "s (cloud stamps) after which a lost object's id is retired (never "
                "handed out again); not above track_timeout: retired when lost", low=0.0, high=86400.0)
        d = SceneConfig()
        declare(self, "max_points", d.max_points, "clouds with more points are randomly subsampled to this many "
                "while being read (bounds time and memory)", low=16)
        declare(self, "sample_points", d.sample_points, "points above the table (random subset) that are "
                "clustered into objects", low=16, high=1_000_000)
        declare(self, "object_points", d.object_points, "at most this many points per object (random subset) "
                "for outlier removal and encoding", low=16, high=1_000_000)
        declare(self, "crop", d.crop, "keep only points inside the box crop_min..crop_max (table frame)")
        declare(self, "crop_min", list(d.crop_min), "x, y, z lower corner of the crop box, m", length=3,
                check=self._crop_check("crop_max", below=True))
        declare(self, "crop_max", list(d.crop_max), "x, y, z upper corner of the crop box, m", length=3,
                check=self._crop_check("crop_min", below=False))
        declare(self, "remove_plane", d.remove_plane, "remove the table plane (RANSAC: a plane within "
                "plane_max_tilt of horizontal and plane_max_offset of z = 0, reaching beyond the objects) and "
                "the points below it")
        declare(self, "plane_distance", d.plane_distance, "RANSAC inlier distance, m", low=1e-5, high=1.0)
        declare(self, "plane_max_tilt", d.plane_max_tilt, "largest tilt of the table plane, degrees", low=0.0,
                high=90.0)
        declare(self, "plane_max_offset", d.plane_max_offset, "largest |height| of the table plane, m", low=0.0)
        declare(self, "voxel_size", d.voxel_size, "voxel grid downsampling size, m; 0 = off", low=0.0, high=1.0)
        declare(self, "cluster_tolerance", d.cluster_tolerance, "m, cell side of the clustering: surfaces closer "
                "than this are one object; objects closer than about 3.5 times this may merge", low=0.001,
                high=1.0)
        declare(self, "cluster_max_size", d.cluster_max_size, "m, clusters wider than this along an axis are not "
                "objects", low=0.01, high=100.0)
        declare(self, "max_objects", d.max_objects, "at most this many objects (the largest) per cloud", low=1,
                high=1000)
        declare(self, "outlier_neighbors", d.outlier_neighbors, "statistical outlier removal per object: "
                "neighbours per point; 0 = off", low=0, high=1000)
        declare(self, "outlier_std_ratio", d.outlier_std_ratio, "statistical outlier removal: std-dev ratio",
                low=0.1, high=100.0)
        declare(self, "min_points", d.min_points, "clusters with fewer points are not objects; fewer points in "
                "all: no feature (warning)", low=1)
        declare(self, "publish_markers", True, "publish each object's outline and id on object_markers")
        declare(self, "feature_points", 1024, "points of each object sent with its feature (ShapeFeature.points, "
                "what plan_push pushes on); 0 = none", low=0, high=100_000)
        t = PoseConfig()
        declare(self, "track_poses", True, "publish each tracked object's pose and twist on tracked_state and its "
                "state at a push's onset on initial_state")
        declare(self, "track_com", "footprint", "centre of mass of a new track's reference: 'footprint' = the "
                "view's geometry before outlier removal (the axis of a surface of revolution, else the top faces' "
                "outline where they span the footprint, else the solid under the view's surface), taken again from "
                "the grown model as turns show new sides, 'model' = the encoder's centre-of-mass head in x-y (the "
                "footprint for models without a head)", choices=COM_SOURCES)
        declare(self, "track_tilt", t.tilt, "register in 6 degrees of freedom; false: yaw and translation only "
                "(objects that stay upright)")
        declare(self, "track_onset_distance", t.onset_distance, "m from the rest pose: the object moves (a push)",
                low=0.0005, high=1.0)
        declare(self, "track_onset_angle", t.onset_angle, "rad from the rest orientation: the object moves",
                low=0.001, high=math.pi)
        declare(self, "track_onset_frames", t.onset_frames, "moving clouds before a push's initial state is "
                "fitted and published", low=1, high=30)
        declare(self, "track_deceleration", t.deceleration, "m/s^2, the sliding deceleration (friction mu g) "
                "assumed when too few clouds of a push fix it", low=0.01, high=100.0)
        declare(self, "track_max_gap", t.max_gap, "s without a pose (no cloud, or clouds the model explains too "
                "little of) after which a track's motion history is dropped and the pose it is seen at next is its "
                "rest pose (no push is inferred across the gap)", low=0.01, high=3600.0)
        self.predictor = None  # the encoder: loaded on configure, released on cleanup
        self._rng = np.random.default_rng(0)
        self.tracker = Tracker()
        self.poses = PoseTracker()
        self.states: list[ObjectState] = []  # of the last cloud, for tracked_state
        self.onsets: list[ObjectState] = []  # of the last cloud, for initial_state
        self.pushes = 0  # onsets published
        self.tracking_note = ""  # the last thing pose tracking skipped, and why
        self.retired = 0  # tracks ended (their ids are not handed out again)
        self.last_retirement = ""  # the last one's id and why
        self.lost = 0  # tracks lost from view (their ids wait track_memory for their shapes)
        self.last_loss = ""
        self.processed = 0  # clouds that gave at least one feature
        self.published = 0  # features
        self.last_error = ""
        self.last_ms = 0.0  # processing time of the last cloud
        self._warn = ReasonThrottle(self.get_logger(), "warning", 2.0)
        self._note = ReasonThrottle(self.get_logger(), "info", 10.0)
        self._tf_buffer = self._tf_listener = None
        self.refused = 0
        self._refusals = RefusalWindow()
        self.diagnostics = Diagnostics(self, "clouds", self._diagnose)
        self.start()  # autostart: configure + activate

    # -------------------------------------------------------------------------------------------- lifecycle
    def configure(self) -> None:
        p = self.get_parameter
        parse_transform(p("sensor_transform").value)  # a bad one: configure fails with the reason
        self.config()  # the segmentation settings must make a SceneConfig
        self.predictor = load_predictor(self, p("model_path").value, p("device").value, int(p("num_threads").value))
        self._warm_up()
        self.tracker = Tracker()
        self.poses = PoseTracker()
        if p("use_tf").value and tf2_available():
            import tf2_ros

            self._tf_buffer = tf2_ros.Buffer()
            # Its own node and thread: a lookup may wait (tf_timeout) inside this node's cloud callback.
            self._tf_listener = tf2_ros.TransformListener(self._tf_buffer, None, spin_thread=True)
        self.pub = self.configured_publisher(ShapeFeature, "shape_feature", FEATURE_QOS)
        self.pub_markers = self.configured_publisher(MarkerArray, "object_markers", LATCHED)
        self.pub_state = self.configured_publisher(ObjectState, "tracked_state", STATE_QOS)
        self.pub_initial = self.configured_publisher(ObjectState, "initial_state", STATE_QOS)

    def activate(self) -> None:
        self.active_subscription(PointCloud2, "cloud", self.on_cloud, CLOUD_SENSOR_QOS)

    def cleanup(self) -> None:
        self._stop_tf()
        self._tf_buffer = None
        self.tracker = Tracker()
        self.poses = PoseTracker()
        self.predictor = None  # the encoder's tensors go with the last reference
        import gc

        gc.collect()

    def describe(self) -> str:
        use_tf = self.get_parameter("use_tf").value
        frames = "tf2" if self._tf_buffer is not None else ("no tf2 (tf2_ros not importable)" if use_tf else
                                                            "tf off (use_tf false)")
        sensor = self.get_parameter("sensor_frame").value
        return (f"clouds in '{self.table_frame}'" + (f", '{sensor}' (sensor_transform)" if sensor else "")
                + f", other frames: {frames}; "
                + ("single object" if self.get_parameter("single_object").value else "several objects")
                + f"; model {self.predictor.model_id if self.predictor is not None else '-'}")

    def _warm_up(self) -> None:
        """One synthetic table with objects through segmentation, tracking and encoding before `ready`: the first
        real cloud otherwise paid for scipy's imports (half a second for scipy.optimize alone)."""
        from ..perception.synthetic import tabletop_scene

        scene = tabletop_scene(5000, rng=np.random.default_rng(0))
        found = segment(scene.points, SceneConfig(), scene.camera, np.random.default_rng(0))
        ids = Tracker().update([o.centroid for o in found.objects], 0.0)
        warm = PoseTracker()
        objects = dict(zip(ids, found.objects))
        for k in range(3):  # capture, then registration and the twist, as track() calls them
            warm.update(0.1 * k, [(i, o.cluster) for i, o in objects.items()],
                        surface_of=lambda i: found.surface(objects[i]))
        outline_xy(found.objects[0].points)
        self.predictor.encode(found.objects[0].points)

    # ------------------------------------------------------------------------------------------------ settings
    def _crop_check(self, other: str, below: bool):
        """A parameter check: crop_min must lie below crop_max on every axis (and crop_max above crop_min)."""
        def check(value) -> str | None:
            if not self.has_parameter(other) or len(value) != 3:
                return None
            there = list(self.get_parameter(other).value)
            lo, hi = (value, there) if below else (there, value)
            if len(there) == 3 and not all(a < b for a, b in zip(lo, hi)):
                return f"must lie {'below' if below else 'above'} {other} {there} on every axis, got {list(value)}"
            return None
        return check

    def config(self) -> SceneConfig:
        """The segmentation settings, read from the parameters now (they may change at run time)."""
        p = {name: self.get_parameter(name).value for name in SceneConfig.__dataclass_fields__}
        p["crop_min"], p["crop_max"] = tuple(p["crop_min"]), tuple(p["crop_max"])
        return SceneConfig(**p)

    def transform_to_table(self, header: Header) -> RigidTransform | None:
        """The transform of the cloud's frame into the table frame (None: it is the table frame); ValueError
        with the reason when it is not known."""
        frame = header.frame_id
        if frame == self.table_frame:
            return None
        sensor = self.get_parameter("sensor_frame").value
        if frame and frame == sensor:
            return parse_transform(self.get_parameter("sensor_transform").value)
        hint = (f"set sensor_frame:={frame or '<frame>'} and sensor_transform:=[x, y, z, qx, qy, qz, qw] (the pose "
                f"of the cloud's frame in '{self.table_frame}'), or publish clouds in '{self.table_frame}'")
        if not frame:
            raise ValueError(f"frame_id is empty: the cloud's frame is unknown ({hint})")
        if self._tf_buffer is None:
            why = ("tf2_ros cannot be imported here" if self.get_parameter("use_tf").value else "use_tf is false")
            raise ValueError(f"frame_id '{frame}' is not the table frame '{self.table_frame}' and no transform is "
                             f"known: {why}, and sensor_frame is '{sensor}' ({hint})")
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        try:
            tf = self._tf_buffer.lookup_transform(self.table_frame, frame, Time.from_msg(header.stamp),
                                                  Duration(seconds=float(self.get_parameter("tf_timeout").value)))
        except tf2_ros.TransformException as exc:
            raise ValueError(f"frame_id '{frame}' is not the table frame '{self.table_frame}' and tf has no "
                             f"transform at the cloud's stamp: {exc}") from None
        t, r = tf.transform.translation, tf.transform.rotation
        return parse_transform([t.x, t.y, t.z, r.x, r.y, r.z, r.w], f"tf transform {frame} -> {self.table_frame}")

    # -------------------------------------------------------------------------------------------------- work
    def process(self, msg: PointCloud2) -> tuple[list[ShapeFeature], MarkerArray, str]:
        """Cloud -> (features, markers, reason); reason says why there is no feature (then features is empty; an
        empty reason with no feature: only parts of tracked objects were seen, see last_tracking_note).
        The tracked states and onsets of the cloud are left in self.states / self.onsets. ValueError for a cloud
        that cannot be read at all (layout, unknown frame)."""
        self.states, self.onsets = [], []
        to_table = self.transform_to_table(msg.header)
        cfg = self.config()
        pts = cloud_to_xyz(msg, skip_nans=True, max_points=cfg.max_points, rng=self._rng)
        header = Header(stamp=msg.header.stamp, frame_id=self.table_frame)
        if len(pts) == 0:
            reason = "the cloud has no finite points" if cloud_size(msg) else "the cloud is empty"
            return [], self.markers(header, []), reason
        scene = segment(pts, cfg, to_table, self._rng)
        if scene.dropped:
            self.get_logger().debug(f"not objects: {'; '.join(scene.dropped)}")
        stamp_ns = time_to_ns(msg.header.stamp) or self.get_clock().now().nanoseconds
        t = stamp_ns * 1e-9
        p = self.get_parameter
        self.tracker.configure(p("id_prefix").value, p("track_gate").value, p("track_timeout").value,
                               p("track_memory").value)
        if not scene.objects:  # the tracks still age: an emptied table retires them
            self.tracker.update(np.zeros((0, 3)), t)
            self._take_retired()
            return [], self.markers(header, []), scene.reason
        centroids = np.array([o.centroid for o in scene.objects])
        signatures = [shape_signature(o.points) for o in scene.objects]  # ids through fast pushes
        if p("single_object").value:
            chosen = self.tracker.follow(centroids, t, p("object_id").value, signatures)
            labelled = [(p("object_id").value, scene.objects[chosen])]
            if len(scene.objects) > 1:
                self._note(f"{len(scene.objects)} objects in the cloud; single_object publishes only the one "
                           f"tracked as '{labelled[0][0]}' (set single_object false for one feature per object)",
                           "several objects")
        else:
            labelled = list(zip(self.tracker.update(centroids, t, signatures), scene.objects))
        if self.tracker.parts:  # the id's feature and pose stay the whole object's
            part_of = {id(scene.objects[i]) for i in self.tracker.parts}
            self.tracking_note = "; ".join(f"{object_id}: only a part seen ({len(obj.points)} points), its feature "
                                           f"and pose hold" for object_id, obj in labelled if id(obj) in part_of)
            self._note(self.tracking_note, "part of an object")
            labelled = [(object_id, obj) for object_id, obj in labelled if id(obj) not in part_of]
        self._take_retired()
        if not labelled:  # nothing wrong with the cloud: no refusal (the note says what was seen)
            return [], self.markers(header, []), ""
        features = []
        # the plane found under the objects (it may lie mm off z = 0): the topple head's support counts from it
        plane = scene.plane
        heights = [plane.height_at(*obj.centroid[:2]) if plane is not None else 0.0 for _, obj in labelled]
        codes = self.predictor.encode_many([obj.points for _, obj in labelled], heights)  # one encoder pass
        for (object_id, obj), code in zip(labelled, codes):
            features.append(ShapeFeature(
                header=header, object_id=object_id, model_id=self.predictor.model_id,
                feature=np.asarray(code.feature, dtype=np.float32).reshape(-1).tolist(),
                heading=float(code.heading), centroid=point(code.centroid), half_extents=vector3(code.half_extents),
                num_points=int(len(obj.points)), points=self.feature_points(obj.points, header)))
        if p("track_poses").value:
            self.track(labelled, codes, heights, t, header, scene)
        return features, self.markers(header, labelled), ""

    def _take_retired(self) -> None:
        for object_id, why in self.tracker.take_losses():
            self.lost += 1
            self.last_loss = f"{object_id}: {why}"
            self.get_logger().info(f"track {self.last_loss}; its id waits track_memory for an object of its shape")
        for object_id, why in self.tracker.take_retired():
            self.retired += 1
            self.last_retirement = f"{object_id}: {why}"
            self.get_logger().info(f"track {self.last_retirement}")

    def pose_config(self) -> PoseConfig:
        p = self.get_parameter
        return PoseConfig(tilt=bool(p("track_tilt").value), onset_distance=float(p("track_onset_distance").value),
                          onset_angle=float(p("track_onset_angle").value),
                          onset_frames=int(p("track_onset_frames").value),
                          deceleration=float(p("track_deceleration").value), max_gap=float(p("track_max_gap").value))

    def track(self, labelled, codes, heights, t: float, header: Header, scene: Scene) -> None:
        """Pose tracking of the labelled objects (their ids from the id tracker; `scene` the segmentation they
        come from) into self.states / self.onsets."""
        self.poses.config = self.pose_config()
        # a pose track goes with its id: retired ids, and an id the id tracker just (re)started (single_object
        # restarts object_id on whatever it sees after losing it), never inherit an old reference
        fresh = {tr.id for tr in self.tracker.tracks if tr.hits == 1}
        keep = [tr.id for tr in self.tracker.tracks if tr.id not in fresh] + [tr.id for tr in self.tracker.lost]
        for gone in self.poses.forget(keep):
            self.tracking_note = f"{gone}: pose track retired (" + ("id restarted on another detection)" if gone
                                                                   in fresh else "its id retired)")
        height = float(np.median(heights)) if heights else 0.0
        seen = {object_id: (obj, code) for (object_id, obj), code in zip(labelled, codes)}
        head = self.get_parameter("track_com").value == "model" and self.predictor.estimates_com

        def com_of(object_id: str, points: np.ndarray) -> np.ndarray:
            code = seen[object_id][1]
            # the object's whole surface, without outlier removal: it trims a top face's far edge
            com = footprint_com(points, height)
            # 'model': the head's x-y; the height of the solid under the view (the head's is 4 mm high)
            return np.array([*code.centroid[:2], com[2]]) if head else com

        update = self.poses.update(t, [(object_id, obj.whole) for object_id, obj in labelled], com_of, height,
                                   lambda object_id: scene.surface(seen[object_id][0]), refine_com=not head)
        if update.notes:
            self.tracking_note = update.notes[-1]
        self.states = [self.state_msg(s, header) for s in update.states]
        self.onsets = [self.state_msg(s, Header(stamp=ns_to_time(int(round(s.t * 1e9))), frame_id=header.frame_id))
                       for s in update.onsets]

    @staticmethod
    def state_msg(state: TrackedState, header: Header) -> ObjectState:
        return object_state(header.frame_id, header.stamp, state.object_id, state.position, state.orientation,
                            state.linear, state.angular)

    def feature_points(self, points: np.ndarray, header: Header) -> PointCloud2:
        """At most `feature_points` of an object's points (a random subset), for plan_push's contact geometry."""
        n = int(self.get_parameter("feature_points").value)
        if n <= 0:
            return PointCloud2()
        # a generator of its own: the segmentation's stream (self._rng) stays as it was without this step
        return xyz_to_cloud(random_rows(points, n, np.random.default_rng(0)), header.frame_id, header.stamp)

    def markers(self, header: Header, labelled) -> MarkerArray:
        """DELETEALL, then per object a LINE_STRIP of its x-y convex hull on the table (z = 0, ns object_outline)
        and its id as text above it (ns object_id); empty when publish_markers is off or nobody listens."""
        if not self.get_parameter("publish_markers").value or self.pub_markers.get_subscription_count() == 0:
            return MarkerArray()
        out = [Marker(header=header, action=Marker.DELETEALL)]
        for k, (object_id, obj) in enumerate(labelled):
            r, g, b = PALETTE[zlib.crc32(object_id.encode()) % len(PALETTE)]
            colour = ColorRGBA(r=r, g=g, b=b, a=1.0)
            ring = outline_xy(obj.points)
            line = Marker(header=header, ns="object_outline", id=k, type=Marker.LINE_STRIP, action=Marker.ADD,
                          color=colour, points=[Point(x=float(x), y=float(y), z=0.0) for x, y in ring])
            line.scale.x = 0.004
            line.pose.orientation.w = 1.0
            text = Marker(header=header, ns="object_id", id=k, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                          color=colour, text=object_id)
            c = obj.centroid
            text.pose.position = Point(x=float(c[0]), y=float(c[1]), z=float(obj.points[:, 2].max()) + 0.03)
            text.pose.orientation.w = 1.0
            text.scale.z = 0.025
            out += [line, text]
        return MarkerArray(markers=out)

    def _diagnose(self) -> Report:
        level = self._refusals.level(self.refused)
        return level, (f"last refusal: {self.last_error}" if level != OK else "encoding clouds"), {
            "model_id": self.predictor.model_id if self.predictor is not None else "",
            "model_loaded": self.predictor is not None, "clouds_with_features": self.processed,
            "features": self.published, "clouds_refused": self.refused, "last_refusal": self.last_error,
            "last_cloud_ms": f"{self.last_ms:.1f}", "tracked_objects": len(self.tracker.tracks),
            "pose_tracks": len(self.poses.tracks), "pushes_detected": self.pushes,
            "tracks_retired": self.retired, "last_retirement": self.last_retirement, "tracks_lost": self.lost,
            "last_loss": self.last_loss,
            "last_tracking_note": self.tracking_note}

    def _reject(self, msg: PointCloud2, reason: str) -> None:
        self.refused += 1
        self.last_error = reason
        self._warn(f"cloud ({cloud_size(msg)} points, frame '{msg.header.frame_id}') ignored: {reason}", reason)

    def on_cloud(self, msg: PointCloud2) -> None:
        t0 = time.monotonic()
        try:
            features, markers, reason = self.process(msg)
        except ValueError as exc:
            self._reject(msg, str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - one bad cloud must not kill the node
            self._reject(msg, f"{type(exc).__name__}: {exc}")
            return
        for f in features:
            self.pub.publish(f)
        for state in self.states:
            self.pub_state.publish(state)
        for state in self.onsets:
            self.pub_initial.publish(state)
        self.pushes += len(self.onsets)
        if markers.markers:
            self.pub_markers.publish(markers)
        self.last_ms = 1e3 * (time.monotonic() - t0)
        if not features:  # without a reason: only parts of tracked objects, whose ids hold; nothing to publish
            if reason:
                self._reject(msg, reason)
            return
        self.processed += 1
        self.published += len(features)
        self.get_logger().debug(f"{len(features)} feature(s) from {cloud_size(msg)} points in {self.last_ms:.1f} ms")

    def destroy_node(self) -> None:
        self._stop_tf()  # destroyed while configured: the listener's thread and node still go
        super().destroy_node()

    def _stop_tf(self) -> None:
        listener, self._tf_listener = self._tf_listener, None
        if listener is not None:  # stop its thread and its own node (tf2_ros only does so when collected)
            if getattr(listener, "executor", None) is not None:
                listener.executor.shutdown()
            thread = getattr(listener, "dedicated_listener_thread", None)
            if thread is not None:
                thread.join(2.0)
            if getattr(listener, "node", None) is not None:
                listener.node.destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(PerceptionNode, "perception", args)


if __name__ == "__main__":
    sys.exit(main())
