"""The perception node: preprocessing, the latched ShapeFeature, and clouds it must refuse without dying."""
from __future__ import annotations

import time

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField

from physdyn_ros.msg import ShapeFeature
from physdyn_ros.nodes.perception_node import FEATURE_QOS, PerceptionNode, Preprocess, preprocess
from physdyn_ros.ros.cloud import xyz_to_cloud
from physdyn_ros.ros.convert import ns_to_time
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


def test_plane_removal_takes_the_table_not_the_object():
    obj = box_surface(3000)
    cleaned = preprocess(np.vstack([obj, table(20000)]), Preprocess(remove_plane=True, outlier_neighbors=0))
    assert len(cleaned) < 1.05 * len(obj)
    assert np.percentile(cleaned[:, 2], 1) > 0.004  # the table is gone
    # no table in view: the box's own faces (top at 8 cm, bottom at 0 but small) are left alone
    alone = preprocess(obj, Preprocess(remove_plane=True, outlier_neighbors=0, plane_max_offset=0.02))
    assert len(alone) > 0.8 * len(obj)
    # a tilted or raised plane is not the table
    raised = preprocess(np.vstack([obj, table(20000, z=0.3)]), Preprocess(remove_plane=True, outlier_neighbors=0))
    assert len(raised) == len(obj) + 20000


def test_crop_voxel_and_outliers():
    obj = box_surface(5000)
    far = np.array([[3.0, 3.0, 3.0], [0.5, 0.5, 0.5]])  # a stray point far away, another in the crop box
    cfg = Preprocess(crop=True, crop_min=(-1, -1, -0.05), crop_max=(1, 1, 1), outlier_neighbors=20)
    cleaned = preprocess(np.vstack([obj, far]), cfg)
    assert not np.any(np.all(np.isclose(cleaned, far[0]), axis=1))
    assert not np.any(np.all(np.isclose(cleaned, far[1]), axis=1))  # statistical outlier
    voxel = preprocess(obj, Preprocess(voxel_size=0.01, outlier_neighbors=0))
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
    assert 1500 < f.num_points <= 2000


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
    (lambda: xyz_to_cloud(box_surface(10), "world"), "only 10 points left"),
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
    feature = node.encode_cloud(msg)
    elapsed = time.monotonic() - t0
    node.destroy_node()
    assert feature.num_points <= 50_000
    assert elapsed < 5.0, f"a 10M-point cloud took {elapsed:.1f} s"


def test_throttle_is_per_reason_kind():
    from physdyn_ros.ros.throttle import ReasonThrottle

    now, logged = [0.0], []
    warn = ReasonThrottle(logged.append, 2.0, clock=lambda: now[0])
    assert warn("a", "the cloud is empty") and warn("b", "only 10 points left")
    now[0] = 1.0
    assert not warn("c", "only 12 points left")  # the same kind: the count differs, the reason does not
    assert warn("d", "frame_id 'camera' is not the table frame")
    now[0] = 2.5
    assert warn("e", "only 9 points left")
    assert logged == ["a", "b", "d", "e (1 more like it since the last one)"]


def test_different_bad_clouds_are_each_reported(tiny_model):
    """Issue 14.7: over DDS, two different bad clouds 1.5 s apart were reported as one (a single 2 s throttle)."""
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
        assert wait_for(lambda: any("ready:" in ln for ln in lines), 60), "".join(lines)[-2000:]
        assert wait_for(lambda: pub.get_subscription_count() > 0, 20)
        for msg in (xyz_to_cloud(np.zeros((0, 3)), "world"), xyz_to_cloud(box_surface(500), "camera_optical"),
                    xyz_to_cloud(box_surface(10), "world")):
            pub.publish(msg)
            time.sleep(0.75)
        assert wait_for(lambda: sum("ignored:" in ln for ln in lines) >= 3, 10), "".join(lines)[-3000:]
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        proc.wait(10)
    text = "".join(lines)
    for reason in ("the cloud is empty", "is not the table frame 'world'", "only 10 points left"):
        assert reason in text, text[-3000:]
