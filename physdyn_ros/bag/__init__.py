"""rosbag2 recording and replay of the suite's topics, push reports and bag -> dataset conversion.

Reading and writing bags uses the pure-Python `rosbags` library (no rosbag2 needed); nothing here imports rclpy
or a node. The two commands that need ROS live on the ROS side and use this package: `physdyn record` is the
recorder node (physdyn_ros.nodes.recorder_node, configured by bag.record) and `physdyn replay` is
physdyn_ros.ros.replay. `physdyn report` and `physdyn bag2dataset` therefore run on a machine without ROS
(e.g. the training machine).
"""
