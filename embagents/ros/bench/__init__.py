"""Plain rclpy peers that the ROS bench cases and tests run in their own processes (the other side of the bridge)."""
