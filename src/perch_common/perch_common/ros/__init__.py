"""ROS 2 adapters shared by the stage nodes (the only part of perch_common importing rclpy)."""
