"""What rosbag2 stores in an MCAP file besides the messages: per-channel QoS and the bag metadata record.

`ros2 bag play` replays a topic with the QoS in its channel's `offered_qos_profiles` (so a
transient-local topic stays transient local), and `ros2 bag info` reads the `rosbag2` metadata
record (`serialized_metadata`: the bag description with `version` at the top level). Like rosbag2
Jazzy's MCAP storage plugin (`MCAPStorage::create_topic`), each channel also carries
`topic_type_hash`, the type's RIHS01 hash, which the bag description repeats as each topic's
`type_description_hash` (the reader maps one onto the other). QoS profiles
are rosbags' (`rosbags.interfaces.Qos`) and are written in rosbag2's version-9 layout by rosbags.
Pure Python: no rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# Imported with this module, before any mission: a signal (SIGTERM, SIGINT) that interrupts the first
# import mid-way leaves it half-initialised, and the recording could not be closed.
import yaml

ROSBAG2_VERSION = 9
ROSBAG2_METADATA = "rosbag2"  # metadata record name and its one key, as rosbag2's MCAP plugin writes them
SERIALIZED_METADATA = "serialized_metadata"
DISTRO = "jazzy"
_INFINITE = (9223372036, 854775807)  # rmw's "infinite" duration as sec/nsec


def qos_profile(reliable: bool = True, transient_local: bool = False, depth: int = 10):
    """A rosbags QoS profile with rmw's defaults for everything but reliability, durability and depth."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(*_INFINITE)
    return Qos(QosHistory.KEEP_LAST, int(depth),
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False)


def _yaml(data) -> str:
    """Block-style YAML, keys sorted (as rosbags writes metadata.yaml); libyaml's emitter when built
    with it: 0.3 ms a channel instead of ruamel's 3 ms, paid while a mission is being recorded."""
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
    return yaml.dump(data, Dumper=dumper, default_flow_style=False, sort_keys=True)


def offered_qos_text(profiles: list) -> str:
    """rosbag2's `offered_qos_profiles` text for the publishers' profiles (version-9 layout)."""
    return _yaml(_qos_dicts(profiles)).strip() if profiles else ""


def channel_metadata(profiles: list, type_hash: str = "") -> dict[str, str]:
    """The channel metadata rosbag2 Jazzy writes: the offered QoS profiles and the type's RIHS01 hash."""
    return {"offered_qos_profiles": offered_qos_text(profiles), "topic_type_hash": type_hash}


@dataclass
class TopicRecord:
    """One recorded topic as the bag metadata lists it."""

    name: str
    type: str
    profiles: list = field(default_factory=list)
    count: int = 0
    type_hash: str = ""   # RIHS01_<sha256 hex> of the type description ('' when unknown)


def serialized_metadata(topics: list[TopicRecord], start_ns: int, end_ns: int, file_name: str) -> str:
    """The bag description of the `rosbag2` metadata record (the inside of metadata.yaml's top key)."""
    duration = max(0, int(end_ns) - int(start_ns))
    count = sum(t.count for t in topics)
    return _yaml({
        "version": ROSBAG2_VERSION,
        "storage_identifier": "mcap",
        "relative_file_paths": [file_name],
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": int(start_ns)},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.type, "serialization_format": "cdr",
                                "offered_qos_profiles": _qos_dicts(t.profiles),
                                "type_description_hash": t.type_hash},
             "message_count": t.count}
            for t in topics],
        "compression_format": "",
        "compression_mode": "",
        "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": int(start_ns)},
                   "duration": {"nanoseconds": duration}, "message_count": count}],
        "custom_data": None,
        "ros_distro": DISTRO,
    })


def _qos_dicts(profiles: list) -> list:
    from rosbags.rosbag2.metadata import dump_qos_v9

    return dump_qos_v9(list(profiles))


def add_rosbag2_metadata(writer, topics: list[TopicRecord], start_ns: int, end_ns: int, file_name: str) -> None:
    """Write the `rosbag2` metadata record to an open `mcap.writer.Writer`."""
    writer.add_metadata(ROSBAG2_METADATA,
                        {SERIALIZED_METADATA: serialized_metadata(topics, start_ns, end_ns, file_name)})


def recorded_message_counts(metadata_records: dict) -> dict[str, int] | None:
    """topic -> messages written, from the `rosbag2` metadata record (name -> its dict, as
    McapScan.metadata holds them); None when the bag has no such record (its writer never closed it)."""
    text = metadata_records.get(ROSBAG2_METADATA, {}).get(SERIALIZED_METADATA)
    if not text:
        return None
    try:
        described = yaml.safe_load(text)
        return {t["topic_metadata"]["name"]: int(t["message_count"]) for t in described["topics_with_message_count"]}
    except (yaml.YAMLError, KeyError, TypeError, ValueError):   # a foreign or garbled record: counts unknown
        return None


def lost_message_counts(scan) -> dict[str, int] | None:
    """topic -> messages the bag recorded but a damaged read could not recover (a perch_common.mcap_read
    McapScan; messages whose channel record was lost count as lost); None when the recorded counts are
    unknown (no `rosbag2` record: a recorder killed before closing the file)."""
    recorded = recorded_message_counts(scan.metadata)
    if recorded is None:
        return None
    read: dict[str, int] = {}
    for channel_id, count in scan.counts.items():
        if channel_id in scan.channels:
            topic = scan.channels[channel_id].topic
            read[topic] = read.get(topic, 0) + count
    return {topic: count - read.get(topic, 0) for topic, count in recorded.items() if count > read.get(topic, 0)}
