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
"""Perception core without ROS: a table-top point cloud -> the objects on the table, their tracked ids.

- `frames`: sensor-to-table rigid transforms (static-transform parameters, camera optical frames);
- `scene`: finite points, subsampling, table-plane RANSAC, outlier removal, clustering (`segment`);
- `tracking`: ids stable from cloud to cloud (`Tracker`);
- `registration`, `pose_tracking`: each tracked object's pose, twist and push onsets from its points
  (`PoseTracker`);
- `synthetic`: depth-camera clouds of a table with objects, for tests and benches.

The perception node (physdyn_ros/nodes/perception_node.py) is a thin ROS adapter over this package; nothing here
imports rclpy.
"""
from .frames import RigidTransform, camera_optical_pose, parse_transform
from .scene import Preprocess, Scene, SceneConfig, SceneObject, TablePlane, outline_xy, preprocess, segment
from .pose_tracking import PoseConfig, PoseTracker, TrackedState
from .tracking import Tracker

__all__ = ["RigidTransform", "camera_optical_pose", "parse_transform", "Preprocess", "Scene", "SceneConfig",
           "SceneObject", "TablePlane", "outline_xy", "preprocess", "segment", "Tracker", "PoseConfig", "PoseTracker",
           "TrackedState"]
