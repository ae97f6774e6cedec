"""The ROS 2 nodes: thin rclpy adapters over the simulation core, preprocessing and the Predictor."""
