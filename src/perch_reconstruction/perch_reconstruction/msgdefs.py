"""The bag's message types and their ros2msg schemas.

Schemas are the installed standard definitions concatenated with their dependencies the way rosbag2
stores them (perch_common.ros.msgdefs), so `ros2 bag` and Foxglove decode the files without our packages.
"""

from __future__ import annotations

from perch_common.ros.msgdefs import full_definition

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
POSE_TYPES = (POSE_STAMPED, ODOMETRY)
SUPPORTED = (*IMAGE_TYPES, CAMERA_INFO, *POSE_TYPES, TF_MESSAGE)


def message_definition(type_name: str) -> str:
    """ros2msg text of one of the bag's message types, with its dependencies (from the installed .msg files)."""
    if type_name not in SUPPORTED:
        raise ValueError(f"no message definition for '{type_name}' (supported: {', '.join(sorted(SUPPORTED))})")
    return full_definition(type_name)
