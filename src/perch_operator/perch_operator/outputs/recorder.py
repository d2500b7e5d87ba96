"""Record a mission to one MCAP file: every /perch topic, /tf_static and the stage services' introspection events.

Messages are written as received (serialized CDR, no re-encoding) with ros2msg schemas generated
by rosbags, each channel with its publishers' QoS (`offered_qos_profiles`) and the file with
rosbag2's metadata record, so rosbag2, rosbags and Foxglove list, decode and replay them. The
recorder lives in the client's process and subscribes before the goal is sent and waits until the
coordinator's topics and the stage event topics are matched (`wait_matched`); it records what is
published from then on. Outputs do not depend on it: they come from the mission result.

QoS as `ros2 bag record` chooses it (rosbag2's adapt-to-offers): reliable unless a publisher is
best effort; with `latched=True` (`perch record`) transient local when every publisher of the topic
is, so a recording started after a mission holds the latched state (/tf_static, the markers, the
mission's waypoints). A mission's own recording stays volatile: it holds that mission only, not what
an earlier mission left latched. Each channel carries its type's RIHS01 hash (`topic_type_hash`)
as rosbag2 Jazzy writes it: the publishers' hash from discovery, else the installed type's.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from perch_common.conventions import CONFIRM_SERVICE, MISSION_FEEDBACK_TOPIC, MISSION_PRESENCE_PREFIX
from perch_common.ros import bag_format
from perch_common.ros.msgdefs import full_definition, message_class, type_hash
from perch_common.ros.static_transforms import TF_STATIC_TOPIC
from perch_operator.api.presence import observer_writer
from perch_operator.coordinator.stages import STAGES

EVENT_SUFFIX = "/_service_event"
# Where a service event's CDR (4-byte encapsulation header, then service_msgs/ServiceEventInfo: uint8
# event_type, Time stamp, char[16] client_gid, int64 sequence_number 8-aligned) holds what identifies
# its call, read without deserialising the request and reply it carries.
_EVENT_TYPE_AT, _GID_AT, _SEQUENCE_AT = 4, 16, 36
_REQUEST_EVENTS = (0, 1)   # REQUEST_SENT, REQUEST_RECEIVED; 2, 3 are RESPONSE_SENT, RESPONSE_RECEIVED
GRAPH_METADATA = "perch_graph"  # metadata record: the namespace the recorded names live in
# Every stage service plus the operator's own confirm service (relative names).
SERVICES = {s.service: s.srv_type for s in STAGES.values()}
# The coordinator's topics, subscribed by name (not only once discovered), so none is missed: a
# topic found only by discovery is missing whenever the client is faster than the graph query.
MISSION_TOPICS = {MISSION_FEEDBACK_TOPIC: "perch_interfaces/action/PlanPerches_FeedbackMessage",
                  "perch/proposals": "perch_interfaces/msg/Proposal",
                  "perch/waypoints": "perch_interfaces/msg/PerchWaypoint",
                  "perch/waypoint_poses": "geometry_msgs/msg/PoseArray",
                  "perch/surface_review": "perch_interfaces/msg/SurfaceReview",
                  "perch/mission_waypoints": "perch_interfaces/msg/PerchWaypointSet",
                  "perch/markers": "visualization_msgs/msg/MarkerArray",
                  "perch/scan_marker": "visualization_msgs/msg/Marker",
                  "perch/views/image": "sensor_msgs/msg/Image",
                  "perch/views/camera_info": "sensor_msgs/msg/CameraInfo"}


def event_topics() -> dict[str, str]:
    """Service event topic (relative) -> its type name, for every stage service and perch/confirm."""
    from perch_interfaces import srv

    services = dict(SERVICES, **{CONFIRM_SERVICE: srv.Confirm})
    return {name + EVENT_SUFFIX: f"perch_interfaces/srv/{cls.__name__}_Event" for name, cls in services.items()}


class MissionRecorder:
    """Subscribe (raw) to the graph's perch/ topics on `node` and write them to `path` until `close()`.

    Topics are recorded under their full names (/NS/perch/...); the namespace goes in the
    `perch_graph` metadata record so readers can look names up relative to it.
    """

    def __init__(self, node, path: str | Path, prefix: str = "perch", latched: bool = False):
        from mcap.writer import CompressionType, Writer

        self.node = node
        self.path = Path(path)
        self.prefix = node.resolve_topic_name(prefix)
        self.namespace = node.get_namespace().rstrip("/")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="perch_operator")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._subs: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._profiles: dict[str, list] = {}
        self._hashes: dict[str, str] = {}
        self._qos: dict[str, tuple] = {}   # topic -> (reliability, durability) subscribed with
        self.latched = latched
        self._late: set[str] = set()   # topics found once the mission ran (refresh(late=True))
        self._first_ns: int | None = None
        self._last_ns = 0
        self._closed = False
        self._calls: dict[str, dict[bytes, set[str]]] = {}   # event topic -> call -> halves recorded
        self._observer = observer_writer(node)   # it reads every mission's feedback: not a client's reader

    def refresh(self, late: bool = False) -> int:
        """Subscribe to every /perch topic now in the graph and every known service event topic.

        `late` (while the mission ends): topics that appeared since are this mission's own (each
        drone's perch/views/drone_N/...): read transient local where their publishers latch, so what
        they published before they were found is recorded too. Returns how many topics were new."""
        topics = {self.node.resolve_topic_name(name): type_name
                  for name, type_name in dict(event_topics(), **MISSION_TOPICS).items()}
        tf_static = self.node.resolve_topic_name(TF_STATIC_TOPIC)
        # Clients' and observers' markers: nothing is sent on them (a prefix: resolved without its last "/").
        presence = self.node.resolve_topic_name(MISSION_PRESENCE_PREFIX.rstrip("/")) + "/"
        for name, types in self.node.get_topic_names_and_types():
            # tf_static: the mission's input frame -> gravity-aligned frame transform (this graph's namespace).
            if (name.startswith(self.prefix + "/") or name == tf_static) and types and not name.startswith(presence):
                topics.setdefault(name, types[0])
        new = 0
        for name, type_name in topics.items():
            if name not in self._subs:
                if late:
                    self._late.add(name)
                self._subscribe(name, type_name)
                new += 1
            elif self._qos[name] != self._wanted_qos(name) and not self.counts.get(name):
                # Subscribed by name before its publishers were known: now they are, take their QoS
                # (only while nothing was received, so no message is recorded twice).
                self.node.destroy_subscription(self._subs.pop(name))
                self._subscribe(name, type_name)
        return new

    def _wanted_qos(self, topic: str) -> tuple:
        """(reliability, durability) `ros2 bag record` would request from the topic's publishers now."""
        infos = self.node.get_publishers_info_by_topic(topic)
        best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
        latched = (self.latched or topic in self._late) and infos and all(
            i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        return (ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)

    def _subscribe(self, topic: str, type_name: str) -> None:
        msg_class = message_class(type_name)
        reliability, durability = self._qos[topic] = self._wanted_qos(topic)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, durability=durability,
                         reliability=reliability)
        self._subs[topic] = self.node.create_subscription(
            msg_class, topic, lambda data, t=topic, n=type_name: self._write(t, n, data), qos, raw=True)

    def _offered_profiles(self, topic: str) -> list:
        """The QoS of the topic's publishers now, as rosbags profiles (for `ros2 bag play`)."""
        return [qos_from_rclpy(i.qos_profile) for i in self.node.get_publishers_info_by_topic(topic)]

    def _type_hash(self, topic: str, type_name: str) -> str:
        """The publishers' RIHS01 hash (what rosbag2 records), else the installed type's."""
        for info in self.node.get_publishers_info_by_topic(topic):
            if info.topic_type == type_name and info.topic_type_hash.version > 0:
                return str(info.topic_type_hash)
        return type_hash(type_name)

    def _write(self, topic: str, type_name: str, data: bytes) -> None:
        if self._closed:
            return
        if topic not in self._channels:
            if type_name not in self._schemas:
                self._schemas[type_name] = self._writer.register_schema(
                    name=type_name, encoding="ros2msg", data=full_definition(type_name).encode())
            self._profiles[topic] = self._offered_profiles(topic)
            self._types[topic] = type_name
            self._hashes[topic] = self._type_hash(topic, type_name)
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[type_name],
                metadata=bag_format.channel_metadata(self._profiles[topic], self._hashes[topic]))
        now = time.time_ns()
        self._first_ns = now if self._first_ns is None else self._first_ns
        self._last_ns = now
        self._writer.add_message(channel_id=self._channels[topic], log_time=now, publish_time=now,
                                 data=bytes(data), sequence=self.counts.get(topic, 0))
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if topic.endswith(EVENT_SUFFIX) and len(data) >= _SEQUENCE_AT + 8:
            call = bytes(data[_GID_AT:_GID_AT + 16]) + bytes(data[_SEQUENCE_AT:_SEQUENCE_AT + 8])
            half = "request" if data[_EVENT_TYPE_AT] in _REQUEST_EVENTS else "reply"
            self._calls.setdefault(topic, {}).setdefault(call, set()).add(half)

    def recorded_calls(self, topic: str) -> tuple[int, list[str]]:
        """On a service event topic: (calls recorded with both request and reply, the half each
        incomplete call lacks)."""
        calls = self._calls.get(topic, {}).values()
        lacking = [("reply" if halves == {"request"} else "request") for halves in calls if len(halves) < 2]
        return sum(len(halves) == 2 for halves in calls), lacking

    def missing_calls(self, expected: dict[str, int], whole: bool = True) -> list[str]:
        """What the recording lacks of `expected` (event topic -> calls the mission made), one phrase
        per topic: complete calls short of the count and, with `whole` (a mission that succeeded,
        so every call it made was answered), calls recorded with one half only."""
        missing = []
        for topic, count in expected.items():
            complete, lacking = self.recorded_calls(topic)
            service = topic[:-len(EVENT_SUFFIX)]
            if complete < count:
                missing.append(f"{service}: {count - complete} of {count} call(s) not recorded whole")
            elif whole and lacking:
                missing.append(f"{service}: {len(lacking)} call(s) without their {' and '.join(sorted(set(lacking)))}")
        return missing

    def matched(self) -> dict[str, int]:
        """Publishers matched per subscribed topic."""
        return {t: s.get_publisher_count() for t, s in self._subs.items()}

    def wait_matched(self, topics: list[str], spin, timeout: float = 5.0) -> list[str]:
        """Spin until each of `topics` has a publisher matched; returns those still without one."""
        deadline = time.monotonic() + timeout
        while True:
            self.refresh()
            counts = self.matched()
            missing = [t for t in topics if counts.get(t, 0) == 0]
            if not missing or time.monotonic() > deadline:
                return missing
            spin(0.1)

    def add_metadata(self, name: str, values: dict) -> None:
        """A metadata record (string values; others JSON-encoded), shown by `mcap list metadata`."""
        self._writer.add_metadata(name, {k: v if isinstance(v, str) else json.dumps(v) for k, v in values.items()})

    def close(self) -> Path:
        """Stop recording and finish the file (idempotent); returns its path."""
        if not self._closed:
            self._closed = True
            self._writer.add_metadata(GRAPH_METADATA, {"namespace": self.namespace})
            bag_format.add_rosbag2_metadata(
                self._writer, [bag_format.TopicRecord(topic, self._types[topic], self._profiles[topic], count,
                                                       self._hashes[topic])
                               for topic, count in self.counts.items()],
                self._first_ns or 0, self._last_ns, self.path.name)
            for sub in self._subs.values():
                self.node.destroy_subscription(sub)
            self.node.destroy_publisher(self._observer)
            self._writer.finish()
            self._file.close()
        return self.path


def qos_from_rclpy(profile):
    """An rclpy QoSProfile as a rosbags Qos (the enums share rmw's numbering)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    def span(duration) -> QosTime:
        return QosTime(*divmod(int(duration.nanoseconds), 1_000_000_000))

    return Qos(QosHistory(int(profile.history)), int(profile.depth), QosReliability(int(profile.reliability)),
               QosDurability(int(profile.durability)), span(profile.deadline), span(profile.lifespan),
               QosLiveliness(int(profile.liveliness)), span(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))
