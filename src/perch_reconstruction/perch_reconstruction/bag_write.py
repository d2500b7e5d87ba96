"""Write RGB-D frames as a ROS 2 MCAP bag with standard message types (rosbag2 profile).

Besides the images (in `camera_optical_frame`) and camera info for colour and depth, the bag holds
the tf tree a camera driver and a localiser would publish: /tf_static `camera_link ->
camera_optical_frame` (REP 103/105 axes) and, for every frame with a pose, /tf `map ->
camera_link`, so a viewer connects the images to `map` and tf-based consumers find the poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from perch_common.errors import PerchError
from perch_common.outputs import atomic_path
from perch_common.ros import bag_format
from perch_reconstruction import images, msgdefs
from perch_reconstruction.frames import Intrinsics, RGBDFrame


@dataclass(frozen=True)
class BagTopics:
    """Topic names shared by the bag tools and the node's defaults."""

    color: str = "/camera/color/image_raw"
    depth: str = "/camera/depth/image_raw"
    camera_info: str = "/camera/depth/camera_info"
    pose: str = "/camera/pose"
    color_info: str = "/camera/color/camera_info"


TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"
CAMERA_FRAME = "camera_optical_frame"
CAMERA_LINK = "camera_link"
POSE_TYPES = ("pose", "odometry", "tf")   # tf: the poses only as /tf (no pose topic)
PERCH_METADATA = "perch"  # MCAP metadata record carrying the gravity direction (world frame of the poses)


def write_bag(path: str | Path, frames: Iterable[RGBDFrame], intrinsics: Intrinsics, *,
              gravity: np.ndarray | None = None, topics: BagTopics = BagTopics(), compressed: bool = False,
              pose_type: str = "pose", world_frame: str = "map") -> dict:
    """Write every frame (colour, 16UC1 depth in mm, camera info, pose if any); returns counts.

    compressed: colour as JPEG and depth as 16-bit PNG in sensor_msgs/CompressedImage.
    pose_type: "pose" (geometry_msgs/PoseStamped), "odometry" (nav_msgs/Odometry) or "tf" (no pose
    topic); the poses go on /tf in every case. Each message is stamped (header and log time) with
    its frame's `stamp_ns`.
    The bag is written under a temporary name and renamed onto `path` only when complete.
    """
    if pose_type not in POSE_TYPES:
        raise ValueError(f"pose type '{pose_type}': use one of {', '.join(POSE_TYPES)}")
    with atomic_path(path) as partial:  # a failed conversion never replaces an existing bag
        return _write_bag(partial, Path(path), frames, intrinsics, gravity, topics, compressed, pose_type,
                          world_frame)


def _write_bag(path: Path, final: Path, frames, intrinsics, gravity, topics, compressed, pose_type,
               world_frame) -> dict:
    from mcap.well_known import MessageEncoding, SchemaEncoding
    from mcap.writer import CompressionType, Writer
    from mcap_ros2._dynamic import serialize_dynamic

    from perch_common.ros.msgdefs import type_hash
    from perch_reconstruction.tf_buffer import OPTICAL_FROM_LINK

    image_type = msgdefs.COMPRESSED_IMAGE if compressed else msgdefs.IMAGE
    channels = {topics.color: image_type, topics.depth: image_type, topics.camera_info: msgdefs.CAMERA_INFO,
                topics.color_info: msgdefs.CAMERA_INFO, TF_STATIC_TOPIC: msgdefs.TF_MESSAGE,
                TF_TOPIC: msgdefs.TF_MESSAGE}
    if pose_type != "tf":
        channels[topics.pose] = msgdefs.POSE_STAMPED if pose_type == "pose" else msgdefs.ODOMETRY
    counts = {t: 0 for t in channels}
    # A camera driver's sensor topics: reliable, volatile, depth 10 (what `ros2 bag play` re-offers);
    # /tf_static as a static broadcaster latches it, /tf as tf broadcasters send it.
    sensor = [bag_format.qos_profile(reliable=True, transient_local=False, depth=10)]
    qos = {t: sensor for t in channels}
    qos[TF_STATIC_TOPIC] = [bag_format.qos_profile(reliable=True, transient_local=True, depth=1)]
    qos[TF_TOPIC] = [bag_format.qos_profile(reliable=True, transient_local=False, depth=100)]
    link_from_optical = np.linalg.inv(OPTICAL_FROM_LINK)   # camera_link <- camera_optical_frame
    first_ns = last_ns = None
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="perch_reconstruction")
        ids, encoders, schemas = {}, {}, {}
        for type_name in set(channels.values()):
            text = msgdefs.message_definition(type_name)
            schemas[type_name] = writer.register_schema(type_name, SchemaEncoding.ROS2, text.encode())
            encoders[type_name] = serialize_dynamic(type_name, text)[type_name]

        def put(topic: str, fields: dict, stamp: int) -> None:
            if topic not in ids:  # channels appear with their first message (no empty pose topic)
                ids[topic] = writer.register_channel(
                    topic, MessageEncoding.CDR, schemas[channels[topic]],
                    bag_format.channel_metadata(qos[topic], type_hash(channels[topic])))
            writer.add_message(ids[topic], log_time=stamp, data=encoders[channels[topic]](fields), publish_time=stamp,
                               sequence=counts[topic])
            counts[topic] += 1

        for frame in frames:
            stamp = frame.stamp_ns
            if first_ns is None:   # the camera's mount, once, latched
                put(TF_STATIC_TOPIC, {"transforms": [images.transform_fields(
                    link_from_optical, stamp, CAMERA_LINK, CAMERA_FRAME)]}, stamp)
            first_ns = stamp if first_ns is None else first_ns
            last_ns = stamp
            depth_mm = np.clip(np.round(frame.depth * 1000.0), 0, 65534).astype(np.uint16)
            if compressed:
                put(topics.color, images.compressed_fields(frame.color, "jpeg", stamp, CAMERA_FRAME), stamp)
                put(topics.depth, images.compressed_fields(depth_mm, "16UC1; png", stamp, CAMERA_FRAME), stamp)
            else:
                put(topics.color, images.image_fields(frame.color, "rgb8", stamp, CAMERA_FRAME), stamp)
                put(topics.depth, images.image_fields(depth_mm, "16UC1", stamp, CAMERA_FRAME), stamp)
            put(topics.camera_info, images.camera_info_fields(intrinsics, stamp, CAMERA_FRAME), stamp)
            put(topics.color_info, images.camera_info_fields(intrinsics, stamp, CAMERA_FRAME), stamp)
            if frame.pose is not None:
                put(TF_TOPIC, {"transforms": [images.transform_fields(
                    np.asarray(frame.pose) @ OPTICAL_FROM_LINK, stamp, world_frame, CAMERA_LINK)]}, stamp)
                if pose_type != "tf":
                    fields = (images.pose_stamped_fields(frame.pose, stamp, world_frame) if pose_type == "pose"
                              else images.odometry_fields(frame.pose, stamp, world_frame, CAMERA_FRAME))
                    put(topics.pose, fields, stamp)
        if first_ns is None:
            raise PerchError("no frames to write; the bag was not created")
        if gravity is not None:
            writer.add_metadata(PERCH_METADATA, {"gravity": " ".join(f"{v:.9g}" for v in np.ravel(gravity)),
                                                 "world_frame": world_frame})
        bag_format.add_rosbag2_metadata(
            writer, [bag_format.TopicRecord(topic, channels[topic], qos[topic], counts[topic], type_hash(channels[topic]))
                     for topic in ids],
            first_ns, last_ns, final.name)
        writer.finish()
    return {"path": str(final), "messages": {t: n for t, n in counts.items() if n}, "duration_s": (last_ns - first_ns) / 1e9}

