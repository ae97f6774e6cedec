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
"""Clouds in a camera optical frame end to end: the sim publishes them (cloud_frame: camera), the perception node
turns them into features in the table frame with the static transform the sim announces."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from physdyn_ros.msg import ShapeFeature
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.ros.qos import FEATURE_QOS
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.perception import camera_optical_pose
from physdyn_ros.ros.cloud import cloud_to_xyz
from test_nodes_support import Spinner, tiny_model, wait_for  # noqa: F401 - fixture

EYE, TARGET = [0.5, 0.3, 0.4], [0.0, 0.0, 0.05]


def sim_node(**params) -> SimNode:
    base = dict(real_time_factor=0.0, publish_cloud_rate=5.0, camera_eye=EYE, camera_target=TARGET)
    base.update(params)
    return SimNode(parameter_overrides=[Parameter(k, value=v) for k, v in base.items()])


@pytest.mark.parametrize("source", ["surface", "camera"])
def test_sim_publishes_its_cloud_in_the_camera_optical_frame(rclpy_init, source):
    sim = sim_node(cloud_frame="camera", camera_frame="cam_opt", cloud_source=source)
    client = rclpy_init.create_node("cloud_client")
    clouds: list[PointCloud2] = []
    client.create_subscription(PointCloud2, "cloud", clouds.append, 5)
    pose = camera_optical_pose(EYE, TARGET)
    with Spinner(sim, client):
        assert wait_for(lambda: clouds, 15), "no cloud"
        msg = clouds[-1]
        truth = np.asarray(sim.current_cloud())  # table frame, the object at rest
    assert msg.header.frame_id == "cam_opt"
    cam = cloud_to_xyz(msg).astype(np.float64)
    assert np.all(cam[:, 2] > 0.2)  # in front of the camera: optical z is the viewing direction
    table = pose.apply(cam)
    assert np.allclose(np.sort(table, axis=0), np.sort(truth, axis=0), atol=1e-5)
    # image down is table down: points higher on the object have a smaller optical y
    high, low = table[:, 2] > np.median(table[:, 2]), table[:, 2] < np.median(table[:, 2])
    assert cam[high, 1].mean() < cam[low, 1].mean()


def test_bad_cloud_frame_stops_the_sim(rclpy_init):
    with pytest.raises(ValueError, match="cloud_frame must be one of"):
        sim_node(cloud_frame="optical")


def test_camera_frame_cloud_end_to_end(rclpy_init, tiny_model):
    """Sim camera view in the camera frame -> perception with the transform the sim logs (tf2 is not installed
    here) -> a feature in the table frame whose centroid is that of the visible points."""
    sim = sim_node(cloud_frame="camera", cloud_source="camera", category="cylinder")
    pose = camera_optical_pose(EYE, TARGET)
    perception = PerceptionNode(parameter_overrides=[
        Parameter("model_path", value=str(tiny_model)), Parameter("sensor_frame", value="camera_optical_frame"),
        Parameter("sensor_transform", value=pose.as_list())])
    client = rclpy_init.create_node("feature_client")
    feats: list[ShapeFeature] = []
    client.create_subscription(ShapeFeature, "shape_feature", feats.append, FEATURE_QOS)
    with Spinner(sim, perception, client):
        assert wait_for(lambda: feats, 20), perception.last_error
        visible = np.asarray(sim.current_cloud()).mean(axis=0)
    f = feats[-1]
    assert f.object_id == "object" and f.header.frame_id == "world"
    assert np.linalg.norm([f.centroid.x - visible[0], f.centroid.y - visible[1], f.centroid.z - visible[2]]) < 0.01


@pytest.mark.skipif(importlib.util.find_spec("tf2_msgs") is None, reason="tf2_msgs is not installed (ROS from PyPI)")
def test_sim_publishes_the_camera_pose_on_tf_static(rclpy_init):  # pragma: no cover - needs a full ROS 2 install
    from tf2_msgs.msg import TFMessage

    sim = sim_node(cloud_frame="camera")
    client = rclpy_init.create_node("tf_client")
    got: list = []
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client.create_subscription(TFMessage, "/tf_static", got.append, qos)
    with Spinner(sim, client):
        assert wait_for(lambda: got, 15)
    tf = got[-1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "camera_optical_frame")
    t = tf.transform.translation
    assert np.allclose([t.x, t.y, t.z], EYE)
