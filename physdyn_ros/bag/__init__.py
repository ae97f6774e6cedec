"""rosbag2 recording and replay of the suite's topics, push reports and bag -> dataset conversion.

Reading and writing bags uses the pure-Python `rosbags` library (no rosbag2 needed); only the recorder node
(physdyn_ros.nodes.recorder_node) and `physdyn replay` need rclpy, so `physdyn report` and
`physdyn bag2dataset` also run on a machine without ROS (e.g. the training machine).
"""
