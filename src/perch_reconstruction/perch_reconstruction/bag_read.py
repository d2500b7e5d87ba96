"""Read ROS 2 MCAP bags: summary, raw messages in time order, and synchronised RGB-D frames."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from perch_common.errors import PerchError
from perch_common.ros import bag_format
from perch_reconstruction import images, msgdefs
from perch_reconstruction.bag_write import PERCH_METADATA, TF_STATIC_TOPIC, TF_TOPIC, BagTopics
from perch_reconstruction.frames import Intrinsics, RGBDFrame
from perch_reconstruction.sync import FrameAssembler, PoseBuffer

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class RawMessage:
    """One message as read from a bag: topic, type, time and CDR bytes."""

    topic: str
    type_name: str
    log_time_ns: int
    data: bytes     # CDR, with the 4-byte encapsulation header (what rmw publishes raw)
    schema: object  # mcap Schema, for decoding


def _check_file(path: Path) -> None:
    if path.is_dir():   # `ros2 bag record` writes a folder: its metadata.yaml and the .mcap (or .db3) files
        inside = sorted(path.glob("*.mcap"))
        raise PerchError(f"{path}: is a folder, not a bag file; give the .mcap file in it"
                         + (f" ({inside[0].name})" if len(inside) == 1 else
                            f" (it holds {len(inside)}: one at a time)" if inside else
                            " (it holds none: a .db3 bag needs `ros2 bag convert` to MCAP first)"))
    if not path.is_file():
        raise PerchError(f"{path}: no such bag file")
    with open(path, "rb") as f:
        head = f.read(8)
    if head != MCAP_MAGIC:
        raise PerchError(f"{path}: not an MCAP file (record bags with `ros2 bag record -s mcap` "
                         "or convert frames with `perch bag from-frames`)")


def _scan(path: Path):
    from perch_common.mcap_read import McapReadError, scan_mcap

    try:
        return scan_mcap(path)
    except McapReadError as exc:
        raise PerchError(str(exc)) from None
    except OSError as exc:
        raise PerchError(f"{path}: cannot be read ({exc.strerror})") from None


def bag_info(path: str | Path) -> dict:
    """Topics (type, count), start, duration, Perch metadata and damage; raises PerchError for a file
    that is not an MCAP. A damaged one (chunks failing their CRC, cut short, no summary) is read as
    far as it goes: `problems` says what was lost, `recovered` that the counts are what could be read."""
    path = Path(path)
    _check_file(path)
    scan = _scan(path)
    topics = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        topics[channel.topic] = {"type": schema.name if schema else "", "encoding": channel.message_encoding,
                                 "count": int(scan.counts.get(cid, 0))}
    duration = (scan.end_ns - scan.start_ns) / 1e9 if scan.messages else 0.0
    gravity = scan.metadata.get(PERCH_METADATA, {}).get("gravity")
    lost = None if scan.intact else bag_format.lost_message_counts(scan)
    return {"path": str(path), "messages": int(scan.messages), "start_ns": int(scan.start_ns),
            "duration_s": duration, "topics": dict(sorted(topics.items())),
            "gravity": None if gravity is None else [float(v) for v in gravity.split()],
            "metadata": sorted(scan.metadata), "problems": list(scan.problems), "recovered": not scan.intact,
            "damage": scan.damage(), "lost": lost}


def require_cdr(info: dict, topics: list[str], remedy: str = "") -> None:
    """Raise PerchError naming those of `topics` (bag_info's) that are not CDR-encoded: their bytes are no
    ROS 2 messages to decode or to publish (an MCAP of JSON or Protobuf messages)."""
    foreign = {t: info["topics"][t]["encoding"] for t in topics if info["topics"][t]["encoding"] != "cdr"}
    if foreign:
        listed = ", ".join(f"{t} ({encoding or 'no encoding'})" for t, encoding in foreign.items())
        raise PerchError(f"{info['path']}: {listed} not CDR-encoded, as a ROS 2 bag's messages are (record with "
                         f"ros2 bag record or perch bag{remedy})")


def frames_damage(info: dict, topics: BagTopics = BagTopics()) -> str:
    """What a damaged bag (bag_info) lost, in frames: '' for an intact one. A frame needs its colour and
    its depth image, so the frames lost are the larger of the two topics' losses."""
    if not info["recovered"]:
        return ""
    present = info["topics"]
    count = min(present.get(topics.color, {}).get("count", 0), present.get(topics.depth, {}).get("count", 0))
    lost = info["lost"]
    if lost is None:
        told = f"{count} frame(s) recovered; how many were lost is unknown (the bag was never closed)"
    else:
        frames = max(lost.get(topics.color, 0), lost.get(topics.depth, 0))
        told = f"{count} frame(s) recovered, {frames} lost" if frames else f"{count} frame(s) recovered, none lost"
    return f"damaged bag, read as far as it goes ({told}): " + "; ".join(info["problems"])


def iter_raw(path: str | Path, topics: list[str] | None = None) -> Iterator[RawMessage]:
    """Messages in log-time order (a damaged bag: what can be read, in file order), undecoded."""
    from perch_common.mcap_read import iter_mcap

    path = Path(path)
    _check_file(path)
    _scan(path)
    try:
        for schema, channel, message in iter_mcap(path, topics):
            yield RawMessage(channel.topic, schema.name if schema else "", message.log_time, message.data, schema)
    except PerchError:
        raise
    except Exception as exc:  # damage the walk did not see (the file changed under us)
        raise PerchError(f"{path}: corrupt MCAP data ({type(exc).__name__}: {exc})") from exc


class _Decoder:
    def __init__(self):
        from mcap_ros2.decoder import DecoderFactory

        self._factory = DecoderFactory()
        self._cache = {}

    def __call__(self, raw: RawMessage):
        schema = raw.schema
        if schema.id not in self._cache:
            self._cache[schema.id] = self._factory.decoder_for("cdr", schema)
        return self._cache[schema.id](raw.data)


@dataclass
class BagFrames:
    """What `read_bag_frames` found: the intrinsics, gravity and a frame iterator."""

    intrinsics: Intrinsics
    gravity: np.ndarray | None
    frame_count: int
    has_poses: bool
    frames: Iterator[RGBDFrame]
    assembler: FrameAssembler
    pose_frame_id: str = ""   # header.frame_id of the recorded poses (their world frame)
    damage: str = ""          # what a damaged bag lost ('' for an intact one)


def read_bag_frames(path: str | Path, topics: BagTopics = BagTopics(), depth_scale: float = 0.0,
                    sync_tolerance_ns: int = 5_000_000, pose_tolerance_ns: int = 20_000_000,
                    tf_world_frame: str = "map", tf_camera_frame: str = "") -> BagFrames:
    """Check the bag has the expected topics and return its synchronised frames (lazily decoded).

    Poses (PoseStamped or Odometry on topics.pose) are attached when one lies within
    pose_tolerance_ns of the frame; frames never see a pose when the bag has none.
    """
    info = bag_info(path)
    present = info["topics"]
    if info["recovered"] and info["messages"] == 0:
        raise PerchError(f"{info['damage']}: nothing to reconstruct")
    missing = [t for t in (topics.color, topics.depth, topics.camera_info) if t not in present]
    if missing:
        listing = ", ".join(f"{t} ({v['type']})" for t, v in present.items()) or "none"
        raise PerchError(f"{path}: missing topic(s) {', '.join(missing)}; the bag has: {listing}. "
                         "Pass --color-topic/--depth-topic/--info-topic to name yours")
    for topic, allowed in ((topics.color, msgdefs.IMAGE_TYPES), (topics.depth, msgdefs.IMAGE_TYPES),
                           (topics.camera_info, (msgdefs.CAMERA_INFO,))):
        if present[topic]["type"] not in allowed:
            raise PerchError(f"{path}: topic {topic} has type {present[topic]['type']}, expected "
                             f"{' or '.join(allowed)}")
        if present[topic]["count"] == 0:
            raise PerchError(f"{path}: topic {topic} has no messages")
    read = (topics.color, topics.depth, topics.camera_info, topics.pose, TF_TOPIC, TF_STATIC_TOPIC)
    require_cdr(info, [t for t in read if t in present])
    decode = _Decoder()
    intrinsics = None
    for raw in iter_raw(path, [topics.camera_info]):
        intrinsics = images.intrinsics_from_camera_info(decode(raw), topics.camera_info)
        break
    poses = PoseBuffer(capacity=10**7)
    has_poses = topics.pose in present and present[topics.pose]["type"] in msgdefs.POSE_TYPES
    if not has_poses and TF_TOPIC in present:
        # Poses only as tf (how robots publish them): the chain camera -> ... -> world frame.
        tf_poses = _tf_poses(path, present, topics, decode, tf_world_frame, tf_camera_frame, pose_tolerance_ns)
        if tf_poses is not None:
            poses, has_poses = tf_poses, True
    pose_frame_id = tf_world_frame if has_poses and topics.pose not in present else ""   # tf: the world frame
    if has_poses:
        for raw in iter_raw(path, [topics.pose]):
            msg = decode(raw)
            poses.add(images.stamp_ns(msg), images.pose_from_msg(msg))
            pose_frame_id = pose_frame_id or msg.header.frame_id
    gravity = None if info["gravity"] is None else np.asarray(info["gravity"], np.float64)
    assembler = FrameAssembler(sync_tolerance_ns)

    def frames() -> Iterator[RGBDFrame]:
        for raw in iter_raw(path, [topics.color, topics.depth]):
            msg = decode(raw)
            stamp = images.stamp_ns(msg)
            if raw.topic == topics.color:
                frame = assembler.add_color(stamp, images.color_from_msg(msg, topics.color))
            else:
                frame = assembler.add_depth(stamp, images.depth_from_msg(msg, topics.depth, depth_scale))
            if frame is None:
                continue
            check_sizes(frame, intrinsics, topics)
            frame.pose = poses.lookup(frame.stamp_ns, pose_tolerance_ns) if has_poses else None
            yield frame

    count = min(present[topics.color]["count"], present[topics.depth]["count"])
    return BagFrames(intrinsics, gravity, count, has_poses, frames(), assembler, pose_frame_id,
                     frames_damage(info, topics))


def _tf_poses(path, present: dict, topics: BagTopics, decode, world: str, camera: str,
              tolerance_ns: int) -> PoseBuffer | None:
    """world-from-camera at every colour image's stamp, composed from the bag's /tf and /tf_static
    (camera: the images' header frame_id unless given); None when no chain links the two frames."""
    from perch_reconstruction.tf_buffer import TransformBuffer

    buffer = TransformBuffer(capacity=10**7)
    for raw in iter_raw(path, [t for t in (TF_TOPIC, TF_STATIC_TOPIC) if t in present]):
        buffer.add_message(decode(raw), static=raw.topic == TF_STATIC_TOPIC)
    stamps, poses = [], PoseBuffer(capacity=10**7)
    for raw in iter_raw(path, [topics.color]):
        msg = decode(raw)
        camera = camera or msg.header.frame_id
        stamps.append(images.stamp_ns(msg))
    if not camera or buffer.chain(world, camera) is None:
        return None
    for stamp in stamps:
        pose = buffer.lookup(world, camera, stamp, tolerance_ns)
        if pose is not None:
            poses.add(stamp, pose)
    return poses


def check_sizes(frame: RGBDFrame, intrinsics: Intrinsics, topics: BagTopics) -> None:
    """Colour, depth and camera info must describe the same image size."""
    dh, dw = frame.depth.shape
    ch, cw = frame.color.shape[:2]
    if (ch, cw) != (dh, dw):
        raise PerchError(f"{topics.color} is {cw}x{ch} but {topics.depth} is {dw}x{dh}: publish depth "
                         "registered to colour (same size), e.g. the camera driver's aligned depth topic")
    if (intrinsics.width, intrinsics.height) != (dw, dh):
        raise PerchError(f"{topics.camera_info} describes {intrinsics.width}x{intrinsics.height} but "
                         f"{topics.depth} is {dw}x{dh}: use the camera info of the depth stream")
