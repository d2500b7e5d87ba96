"""The bag's message types, their ros2msg schemas and rosbag2 channel metadata.

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
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
POSE_TYPES = (POSE_STAMPED, ODOMETRY)
SUPPORTED = (*IMAGE_TYPES, CAMERA_INFO, *POSE_TYPES)


def message_definition(type_name: str) -> str:
    """ros2msg text of one of the bag's message types, with its dependencies (from the installed .msg files)."""
    if type_name not in SUPPORTED:
        raise ValueError(f"no message definition for '{type_name}' (supported: {', '.join(sorted(SUPPORTED))})")
    return full_definition(type_name)


# The QoS rosbag2 records for a reliable, volatile publisher with history depth 10 (Jazzy layout);
# `ros2 bag play` reads it back from the channel metadata.
OFFERED_QOS = (
    "- history: 1\n  depth: 10\n  reliability: 1\n  durability: 2\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false\n")


def channel_metadata() -> dict[str, str]:
    return {"offered_qos_profiles": OFFERED_QOS}
