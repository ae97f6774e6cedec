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
"""The perception node: preprocessing, several objects with stable ids, sensor frames, the latched ShapeFeature,
markers, speed, and clouds it must refuse without dying."""
from __future__ import annotations

import math
import sys
import time
import types

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField
from visualization_msgs.msg import Marker, MarkerArray

from physdyn_ros.msg import ShapeFeature
from physdyn_ros.nodes.perception_node import PerceptionNode, Preprocess, preprocess, tf2_available
from physdyn_ros.ros.qos import FEATURE_QOS, LATCHED
from physdyn_ros.perception.synthetic import DEFAULT_OBJECTS, tabletop_scene
from physdyn_ros.ros.cloud import cloud_to_xyz, xyz_to_cloud
from physdyn_ros.ros.convert import ns_to_time, time_to_ns
from test_nodes_support import Spinner, tiny_model, wait_for  # noqa: F401 - fixture

RNG = np.random.default_rng(3)


def box_surface(n: int, half=(0.05, 0.03, 0.04), centre=(0.2, 0.1, 0.04), yaw: float = 0.3) -> np.ndarray:
    """n points on the surface of a yawed box resting on the table."""
    half = np.asarray(half)
    p = RNG.uniform(-1, 1, (n, 3)) * half
    axis = RNG.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(RNG.uniform(-1, 1, n)) * half[axis]
    c, s = np.cos(yaw), np.sin(yaw)
    return p @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + np.asarray(centre)


def table(n: int, z: float = 0.0) -> np.ndarray:
    return np.column_stack([RNG.uniform(-0.5, 0.5, (n, 2)), np.full(n, z) + RNG.normal(0, 0.001, n)])


ALL = 10**6  # sample_points that keeps every point


def test_plane_removal_takes_the_table_not_the_object():
    obj = box_surface(3000)
    cfg = Preprocess(remove_plane=True, outlier_neighbors=0, sample_points=ALL)
    cleaned = preprocess(np.vstack([obj, table(20000)]), cfg)
    assert len(cleaned) < 1.05 * len(obj)
    assert np.percentile(cleaned[:, 2], 1) > 0.004  # the table is gone
    # no table in view: the box's own faces (top at 8 cm, bottom at 0) are left alone, bottom included
    alone = preprocess(obj, cfg)
    assert len(alone) == len(obj)
    # a tilted or raised plane is not the table
    raised = preprocess(np.vstack([obj, table(20000, z=0.3)]), cfg)
    assert len(raised) == len(obj) + 20000


def test_crop_voxel_and_outliers():
    obj = box_surface(5000)
    far = np.array([[3.0, 3.0, 3.0], [0.5, 0.5, 0.5]])  # a stray point far away, another in the crop box
    cfg = Preprocess(crop=True, crop_min=(-1, -1, -0.05), crop_max=(1, 1, 1), outlier_neighbors=20,
                     sample_points=ALL)
    cleaned = preprocess(np.vstack([obj, far]), cfg)
    assert not np.any(np.all(np.isclose(cleaned, far[0]), axis=1))
    assert not np.any(np.all(np.isclose(cleaned, far[1]), axis=1))  # statistical outlier
    voxel = preprocess(obj, Preprocess(voxel_size=0.01, outlier_neighbors=0, sample_points=ALL))
    assert 100 < len(voxel) < 1000
    with pytest.raises(ValueError, match="only 2 points left"):
        preprocess(far, Preprocess(outlier_neighbors=0))


def perception(model, **params) -> PerceptionNode:
    overrides = [Parameter("model_path", value=str(model))] + [Parameter(k, value=v) for k, v in params.items()]
    return PerceptionNode(parameter_overrides=overrides)


def test_cloud_gives_a_latched_shape_feature(rclpy_init, tiny_model):
    node = perception(tiny_model, object_id="mug_7")
    pub_node = rclpy_init.create_node("cloud_source")
    pub = pub_node.create_publisher(PointCloud2, "cloud", 2)
    pts = box_surface(2000)
    with Spinner(node, pub_node):
        msg = xyz_to_cloud(pts, "world", ns_to_time(42 * 10**9))
        assert wait_for(lambda: (pub.publish(msg), node.processed)[1], 10, step=0.1), node.last_error
        # a subscriber that joins afterwards still gets it (transient local, depth 1)
        late = rclpy_init.create_node("late_joiner")
        got: list[ShapeFeature] = []
        late.create_subscription(ShapeFeature, "shape_feature", got.append, FEATURE_QOS)
        with Spinner(late):
            assert wait_for(lambda: got, 10), "late joiner got no feature"
    f = got[0]
    assert f.object_id == "mug_7" and f.model_id == node.predictor.model_id
    assert f.header.frame_id == "world" and f.header.stamp.sec == 42
    assert len(f.feature) == 16 and np.all(np.isfinite(f.feature))
    assert (f.centroid.x, f.centroid.y) == pytest.approx(pts[:, :2].mean(0), abs=0.01)
    assert sorted([f.half_extents.x, f.half_extents.y, f.half_extents.z]) == pytest.approx([0.03, 0.04, 0.05],
                                                                                            abs=0.004)
    assert 400 < f.num_points <= 512  # object_points (the encoder itself uses 128 or 256 of them)


def nan_cloud(n: int = 50) -> PointCloud2:
    return xyz_to_cloud(np.full((n, 3), np.nan, np.float32), "world")


def no_xyz_cloud() -> PointCloud2:
    msg = xyz_to_cloud(box_surface(100), "world")
    msg.fields = [PointField(name="intensity", offset=0, datatype=PointField.FLOAT32, count=1)]
    return msg


@pytest.mark.parametrize("make, reason", [
    (lambda: xyz_to_cloud(np.zeros((0, 3)), "world"), "the cloud is empty"),
    (nan_cloud, "no finite points"),
    (no_xyz_cloud, "no x/y/z field"),
    (lambda: xyz_to_cloud(box_surface(500), "camera_optical"), "is not the table frame 'world'"),
    (lambda: xyz_to_cloud(box_surface(500), ""), "frame_id is empty"),
    (lambda: xyz_to_cloud(box_surface(10), "world"), "only 10 points left"),
    (lambda: xyz_to_cloud(table(20000), "world"), "no object on the table"),
    (lambda: xyz_to_cloud(table(20000, z=0.3) * [1.6, 1.6, 1.0], "world"), "wider than cluster_max_size"),
])
def test_bad_clouds_are_refused_and_the_node_keeps_working(rclpy_init, tiny_model, make, reason):
    node = perception(tiny_model)
    node.on_cloud(make())  # the subscription callback itself, as the executor calls it
    assert node.processed == 0 and reason in node.last_error, node.last_error
    node.on_cloud(xyz_to_cloud(box_surface(500), "world"))
    assert node.processed == 1
    node.destroy_node()


def test_huge_cloud_is_bounded(rclpy_init, tiny_model):
    node = perception(tiny_model, max_points=50_000)
    n = 10_000_000
    pts = np.empty((n, 3), np.float32)
    pts[:] = box_surface(n // 100).astype(np.float32).repeat(100, axis=0)
    msg = xyz_to_cloud(pts, "world")
    del pts
    t0 = time.monotonic()
    features, _, reason = node.process(msg)
    elapsed = time.monotonic() - t0
    node.destroy_node()
    assert len(features) == 1, reason
    assert elapsed < 5.0, f"a 10M-point cloud took {elapsed:.1f} s"


def test_throttle_is_per_reason_kind():
    from physdyn_ros.ros.throttle import ReasonThrottle

    class Logger:
        def warning(self, text: str) -> None:
            logged.append(text)

    now, logged = [0.0], []
    warn = ReasonThrottle(Logger(), "warning", 2.0, clock=lambda: now[0])
    assert warn("a", "the cloud is empty") and warn("b", "only 10 points left")
    now[0] = 1.0
    assert not warn("c", "only 12 points left")  # the same kind: the count differs, the reason does not
    assert warn("d", "frame_id 'camera' is not the table frame")
    now[0] = 2.5
    assert warn("e", "only 9 points left")
    assert logged == ["a", "b", "d", "e (1 more like it since the last one)"]


def test_different_bad_clouds_are_each_reported(tiny_model):
    """Over DDS, two different bad clouds 1.5 s apart are each reported: the log throttles per reason, not with
    one throttle for every warning."""
    import os
    import subprocess
    import sys
    import threading

    import rclpy

    env = dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM="0", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "physdyn_ros.nodes.perception_node", "--ros-args", "-p",
                             f"model_path:={tiny_model}"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True).start()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bad_cloud_source", context=context)
    try:
        pub = node.create_publisher(PointCloud2, "cloud", 10)
        assert wait_for(lambda: any("active:" in ln for ln in lines), 60), "".join(lines)[-2000:]
        assert wait_for(lambda: pub.get_subscription_count() > 0, 20)
        reasons = ("the cloud is empty", "is not the table frame 'world'", "only 10 points left")
        for msg, reason in zip((xyz_to_cloud(np.zeros((0, 3)), "world"),
                                xyz_to_cloud(box_surface(500), "camera_optical"),
                                xyz_to_cloud(box_surface(10), "world")), reasons):
            for _ in range(2):  # a best-effort cloud may be lost (a loaded machine): once more, still < 2 s apart
                pub.publish(msg)
                if wait_for(lambda: any(reason in ln for ln in lines), 0.6):
                    break
        assert wait_for(lambda: sum("ignored:" in ln for ln in lines) >= 3, 10), "".join(lines)[-3000:]
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        proc.wait(10)
    text = "".join(lines)
    for reason in reasons:
        assert reason in text, text[-3000:]


# ------------------------------------------------------------------------------------------------ real sensors
def test_reader_reads_padded_and_plain_layouts_alike():
    pts = box_surface(1000).astype(np.float32)
    pts[::7] = np.nan
    plain = xyz_to_cloud(pts, "world")
    padded = xyz_to_cloud(pts, "world")  # x, y, z, intensity: point_step 16, as many drivers publish
    data = np.zeros((len(pts), 4), np.float32)
    data[:, :3] = pts
    padded.data = data.tobytes()
    padded.point_step, padded.row_step = 16, 16 * len(pts)
    padded.fields.append(PointField(name="intensity", offset=12, datatype=PointField.FLOAT32, count=1))
    finite = pts[np.isfinite(pts).all(axis=1)]
    for msg in (plain, padded):
        np.testing.assert_array_equal(cloud_to_xyz(msg), finite)
    view = cloud_to_xyz(plain, skip_nans=False)  # nothing dropped: the message's own buffer, read-only
    assert not view.flags.writeable and np.array_equal(view, pts, equal_nan=True)


class Listener:
    """A node collecting the perception node's features and markers."""

    def __init__(self, rclpy, name: str) -> None:
        self.node = rclpy.create_node(name)
        self.features: list[ShapeFeature] = []
        self.markers: list[MarkerArray] = []
        self.node.create_subscription(ShapeFeature, "shape_feature", self.features.append, FEATURE_QOS)
        self.node.create_subscription(MarkerArray, "object_markers", self.markers.append, LATCHED)
        self.cloud = self.node.create_publisher(PointCloud2, "cloud", 2)

    def of(self, stamp_ns: int) -> list[ShapeFeature]:
        return [f for f in list(self.features) if time_to_ns(f.header.stamp) == stamp_ns]


def camera_params(scene, **more) -> dict:
    return dict(sensor_frame="camera_optical_frame", sensor_transform=scene.camera.as_list(), **more)


def test_several_objects_in_a_camera_frame_over_dds(rclpy_init, tiny_model):
    """A 100k-point depth-camera cloud of a table with three objects, in the camera's optical
    frame -> three features in the table frame, centroids within 1 cm, and their outlines as markers."""
    scene = tabletop_scene(100_000, rng=np.random.default_rng(7))
    node = perception(tiny_model, single_object=False, id_prefix="thing_", **camera_params(scene))
    lis = Listener(rclpy_init, "feature_listener")
    stamp = 50 * 10**9
    with Spinner(node, lis.node):
        assert wait_for(lambda: lis.cloud.get_subscription_count() > 0, 10)
        msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(stamp))
        assert wait_for(lambda: (lis.cloud.publish(msg), len(lis.of(stamp)) >= 3)[1], 20, step=0.5), \
            node.last_error
        assert wait_for(lambda: lis.markers, 10)
    feats = lis.of(stamp)[:3]
    assert sorted(f.object_id for f in feats) == ["thing_1", "thing_2", "thing_3"]
    assert all(f.header.frame_id == "world" and f.model_id == node.predictor.model_id for f in feats)
    found = np.array([[f.centroid.x, f.centroid.y, f.centroid.z] for f in feats])
    err = [np.linalg.norm(found - c, axis=1).min() for c in scene.centroids]
    assert max(err) < 0.01, err
    marks = lis.markers[-1].markers
    assert marks[0].action == Marker.DELETEALL
    outlines = [m for m in marks if m.ns == "object_outline"]
    texts = {m.text for m in marks if m.ns == "object_id"}
    assert len(outlines) == 3 and all(m.type == Marker.LINE_STRIP and len(m.points) >= 4 for m in outlines)
    assert texts == {"thing_1", "thing_2", "thing_3"} and marks[1].header.frame_id == "world"


def test_ids_stay_stable_while_an_object_is_pushed(rclpy_init, tiny_model):
    """Over DDS, clouds at 30 Hz while the middle object slides 1.5 cm per cloud: every object keeps
    its id; a fourth object put on the table gets a new one."""
    node = perception(tiny_model, single_object=False, **camera_params(tabletop_scene(100)))
    lis = Listener(rclpy_init, "tracking_listener")
    specs = list(DEFAULT_OBJECTS)
    ids: dict[int, set[str]] = {0: set(), 1: set(), 2: set()}
    with Spinner(node, lis.node):
        assert wait_for(lambda: lis.cloud.get_subscription_count() > 0, 10)
        for k in range(12):
            specs[1] = specs[1].moved(dx=0.015)
            scene = tabletop_scene(20_000, objects=specs, rng=np.random.default_rng(k))
            stamp = 10**9 + k * 33_333_333
            msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(stamp))
            assert wait_for(lambda: (lis.cloud.publish(msg), len(lis.of(stamp)) >= 3)[1], 10, step=0.3), \
                node.last_error
            for f in lis.of(stamp):
                c = np.array([f.centroid.x, f.centroid.y, f.centroid.z])
                ids[int(np.argmin(np.linalg.norm(scene.centroids - c, axis=1)))].add(f.object_id)
        assert all(len(v) == 1 for v in ids.values()), ids  # one id per object over the twelve clouds
        assert set.union(*ids.values()) == {"object_1", "object_2", "object_3"}, ids
        specs.append(DEFAULT_OBJECTS[0].moved(dx=-0.35, dy=0.2))
        scene = tabletop_scene(20_000, objects=specs, rng=np.random.default_rng(99))
        stamp = 2 * 10**9
        msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(stamp))
        assert wait_for(lambda: (lis.cloud.publish(msg), len(lis.of(stamp)) >= 4)[1], 10, step=0.3)
    # the cloud may have been sent (and processed) more than once until four features arrived: ids, not copies
    assert sorted({f.object_id for f in lis.of(stamp)}) == ["object_1", "object_2", "object_3", "object_4"]


def test_single_object_mode_keeps_the_configured_id(rclpy_init, tiny_model):
    """The default: one feature per cloud, named object_id, for the object it first saw (the largest) even when
    others are on the table; the ones it ignores are mentioned in the log."""
    node = perception(tiny_model, object_id="mug", **camera_params(tabletop_scene(100)))
    scene = tabletop_scene(20_000, rng=np.random.default_rng(3))
    first, _, _ = node.process(xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(10**9)))
    assert [f.object_id for f in first] == ["mug"]
    target = np.array([first[0].centroid.x, first[0].centroid.y])
    for k in range(1, 5):  # it keeps following that object
        msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(10**9 + k * 10**8))
        feats, _, _ = node.process(msg)
        assert len(feats) == 1 and np.hypot(feats[0].centroid.x - target[0], feats[0].centroid.y - target[1]) < 0.01
    node.destroy_node()


def test_unknown_frame_is_refused_with_the_reason_and_touching_objects_merge(rclpy_init, tiny_model):
    node = perception(tiny_model, single_object=False)
    scene = tabletop_scene(20_000)
    node.on_cloud(xyz_to_cloud(scene.points, "camera_link"))
    assert node.processed == 0 and "frame_id 'camera_link' is not the table frame 'world'" in node.last_error
    if not tf2_available():
        assert "tf2_ros cannot be imported here" in node.last_error, node.last_error
    assert "sensor_frame:=camera_link" in node.last_error  # says how to fix it
    # the same cloud once its frame is known
    node.set_parameters([Parameter("sensor_frame", value="camera_link"),
                         Parameter("sensor_transform", value=scene.camera.as_list())])
    node.on_cloud(xyz_to_cloud(scene.points, "camera_link"))
    assert node.processed == 1 and node.published == 3
    # two boxes whose faces touch: one object (documented), the node keeps serving
    touching = [DEFAULT_OBJECTS[0], DEFAULT_OBJECTS[0].moved(dx=0.1)]
    scene = tabletop_scene(20_000, objects=touching)
    feats, _, _ = node.process(xyz_to_cloud(scene.points, "camera_link"))
    assert len(feats) == 1 and max(feats[0].half_extents.x, feats[0].half_extents.y) > 0.08
    node.destroy_node()


def test_bad_sensor_transform_stops_the_node(rclpy_init, tiny_model):
    with pytest.raises(ValueError, match="zero quaternion"):
        perception(tiny_model, sensor_frame="cam", sensor_transform=[0.0] * 7)


class FakeTf2:
    """Stands in for tf2_ros (not on PyPI): records what the node asks, answers with a fixed transform."""

    def __init__(self, transform: list[float]) -> None:
        from geometry_msgs.msg import TransformStamped

        fake = self
        self.calls: list[tuple] = []
        self.listener_args: tuple = ()
        tf = TransformStamped()
        t, r = tf.transform.translation, tf.transform.rotation
        (t.x, t.y, t.z, r.x, r.y, r.z, r.w) = transform
        self.module = types.ModuleType("tf2_ros")

        class TransformException(Exception):
            pass

        class Buffer:
            def lookup_transform(self, target, source, when, timeout):
                fake.calls.append((target, source, when.nanoseconds, timeout.nanoseconds))
                if source != "cam":
                    raise TransformException(f'"{source}" passed to lookupTransform argument source_frame does '
                                             "not exist.")
                return tf

        class TransformListener:
            def __init__(self, buffer, node, *, spin_thread=False):
                fake.listener_args = (node, spin_thread)

        self.module.Buffer, self.module.TransformListener = Buffer, TransformListener
        self.module.TransformException = TransformException


def test_tf2_gives_the_transform_when_it_is_installed(rclpy_init, tiny_model, monkeypatch):
    """With a full ROS 2 install, frames come from tf2 (faked here: tf2_ros is not on PyPI)."""
    scene = tabletop_scene(20_000)
    fake = FakeTf2(scene.camera.as_list())
    monkeypatch.setitem(sys.modules, "tf2_ros", fake.module)
    node = perception(tiny_model, single_object=False, tf_timeout=0.2)
    assert fake.listener_args == (None, True)  # its own node and thread: a lookup may wait in the callback
    feats, _, reason = node.process(xyz_to_cloud(scene.points, "cam", ns_to_time(7 * 10**9)))
    assert len(feats) == 3, reason
    assert fake.calls == [("world", "cam", 7 * 10**9, 200_000_000)]
    found = np.array([[f.centroid.x, f.centroid.y, f.centroid.z] for f in feats])
    assert max(np.linalg.norm(found - c, axis=1).min() for c in scene.centroids) < 0.01
    node.on_cloud(xyz_to_cloud(scene.points, "elsewhere"))
    assert "tf has no transform at the cloud's stamp" in node.last_error and "elsewhere" in node.last_error
    node.destroy_node()


def test_100k_cloud_with_three_objects_within_budget(rclpy_init):
    """100k points, three objects, the shipped model, one thread: the cloud's way from the message to the three
    features stays within twice the 25 ms goal (p50 CPU time of this process, so other load counts little): a
    guard against a slow path, not the goal itself, which bench/bench_perception.py measures."""
    node = PerceptionNode(parameter_overrides=[Parameter("single_object", value=False),
                                               Parameter("num_threads", value=1)]
                          + [Parameter(k, value=v) for k, v in camera_params(tabletop_scene(100)).items()])
    scene = tabletop_scene(100_000)
    msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(10**9))
    node.process(msg)
    rounds = []  # p50 of 10 clouds, best of 3 rounds: other processes on the machine still cost cache and turbo
    for r in range(3):
        cpu = []
        for k in range(10):
            msg.header.stamp = ns_to_time(10**9 + (10 * r + k) * 33_333_333)
            t = time.process_time()
            feats, _, _ = node.process(msg)
            cpu.append(time.process_time() - t)
        rounds.append(np.median(cpu))
    node.destroy_node()
    assert len(feats) == 3
    assert min(rounds) < 0.05, f"p50 {[round(1e3 * v, 1) for v in rounds]} ms CPU per 100k-point cloud"


def test_the_predictor_addresses_any_tracked_object(rclpy_init, tiny_model):
    """Tracked ids reach the predictor: its service by object_id, and an initial_twist for the object named by its
    object_id parameter (a twist carries no id; docs/nodes.md, "Targeting an object with the predictor")."""
    from geometry_msgs.msg import TwistStamped

    from physdyn_ros.msg import PredictedTrajectory
    from physdyn_ros.nodes.predictor_node import PredictorNode
    from physdyn_ros.ros.qos import LATCHED
    from physdyn_ros.srv import PredictTrajectory
    from test_nodes_support import call

    scene = tabletop_scene(50_000, rng=np.random.default_rng(11))
    node = perception(tiny_model, single_object=False, **camera_params(scene))
    model = Parameter("model_path", value=str(tiny_model))
    predictor = PredictorNode(parameter_overrides=[model, Parameter("initial_pose_source", value="shape_feature"),
                                                   Parameter("horizon", value=10)])
    lis = Listener(rclpy_init, "target_user")
    trajs: list[PredictedTrajectory] = []
    lis.node.create_subscription(PredictedTrajectory, "predicted_trajectory", trajs.append, LATCHED)
    twist_pub = lis.node.create_publisher(TwistStamped, "initial_twist", 10)
    service = lis.node.create_client(PredictTrajectory, "predict_trajectory")
    stamp = 100 * 10**9
    with Spinner(node, predictor, lis.node, threads=6):
        assert wait_for(lambda: lis.cloud.get_subscription_count() > 0, 10)
        msg = xyz_to_cloud(scene.points, "camera_optical_frame", ns_to_time(stamp))
        assert wait_for(lambda: (lis.cloud.publish(msg), len(lis.of(stamp)) >= 3)[1], 40, step=0.5)
        feats = {f.object_id: f for f in lis.of(stamp)}
        for oid, f in feats.items():  # the service, by each tracked id (generous waits: a loaded CI machine)
            req = PredictTrajectory.Request(object_id=oid, horizon=5)
            req.header.frame_id, req.header.stamp = "world", ns_to_time(stamp)
            req.initial_pose.position = f.centroid
            req.initial_twist.linear.x = 0.3
            answers = []  # the predictor may not have received that feature yet: ask again
            assert wait_for(lambda: (answers.append(call(service, req)), answers[-1].success)[1], 20, step=0.2), \
                answers[-1].message
            assert answers[-1].trajectory.object_id == oid
        target = sorted(feats)[1]
        predictor.set_parameters([Parameter("object_id", value=target)])
        twist = TwistStamped()
        twist.header.frame_id, twist.header.stamp = "world", ns_to_time(stamp + 10**7)
        twist.twist.linear.x = 0.3
        twist_pub.publish(twist)
        assert wait_for(lambda: trajs, 10), predictor.last_error
    traj, f = trajs[-1], feats[target]
    assert traj.object_id == target
    p = traj.states[0].pose.position
    # started from that object: its centroid (a re-sent cloud's feature differs by the segmentation's sampling,
    # millimetres), nearer to it than to any other object's
    gaps = {oid: math.hypot(p.x - g.centroid.x, p.y - g.centroid.y) for oid, g in feats.items()}
    assert gaps[target] < 0.01 and min(gaps, key=gaps.get) == target, gaps
