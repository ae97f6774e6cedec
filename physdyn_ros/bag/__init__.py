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
"""rosbag2 recording and replay of the suite's topics, push reports and bag -> dataset conversion.

Reading and writing bags uses the pure-Python `rosbags` library (no rosbag2 needed); nothing here imports rclpy
or a node. The two commands that need ROS live on the ROS side and use this package: `physdyn record` is the
recorder node (physdyn_ros.nodes.recorder_node, configured by bag.record) and `physdyn replay` is
physdyn_ros.ros.replay. `physdyn report` and `physdyn bag2dataset` therefore run on a machine without ROS
(e.g. the training machine).
"""
