"""ROS 2 message definitions (ros2msg text) written into MCAP schemas, and rosbag2 channel metadata.

The definitions are the standard ones (comments stripped), concatenated with their dependencies the
way rosbag2 stores them, so `ros2 bag` and Foxglove decode the files without our packages.
"""

from __future__ import annotations

_SEPARATOR = "=" * 80 + "\n"

_BASE = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
    "sensor_msgs/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
}

_TOP = {
    "sensor_msgs/msg/Image": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
        "uint32 step\nuint8[] data\n", ["std_msgs/Header", "builtin_interfaces/Time"]),
    "sensor_msgs/msg/CompressedImage": (
        "std_msgs/Header header\nstring format\nuint8[] data\n", ["std_msgs/Header", "builtin_interfaces/Time"]),
    "sensor_msgs/msg/CameraInfo": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
        "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
        ["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"]),
    "geometry_msgs/msg/PoseStamped": (
        "std_msgs/Header header\nPose pose\n",
        ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose", "geometry_msgs/Point",
         "geometry_msgs/Quaternion"]),
    "nav_msgs/msg/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist\n",
        ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance", "geometry_msgs/Pose",
         "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/TwistWithCovariance",
         "geometry_msgs/Twist", "geometry_msgs/Vector3"]),
}

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
POSE_TYPES = (POSE_STAMPED, ODOMETRY)


def message_definition(type_name: str) -> str:
    """The full ros2msg text of a supported type, dependencies appended as rosbag2 writes them."""
    if type_name not in _TOP:
        raise ValueError(f"no message definition for '{type_name}' (supported: {', '.join(sorted(_TOP))})")
    text, deps = _TOP[type_name]
    return text + "".join(f"{_SEPARATOR}MSG: {dep}\n{_BASE[dep]}" for dep in deps)


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
