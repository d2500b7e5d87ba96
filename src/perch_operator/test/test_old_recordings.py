"""A recording made before a field was added to a stage request still reads: its own schema decodes it."""

from __future__ import annotations

import numpy as np

from perch_common.ros.msgdefs import full_definition, message_reader

EVENT = "perch_interfaces/srv/Segment_Event"
ADDED = "string request_id\n"   # the field this recording's version of Segment.Request lacked


def old_definition() -> str:
    text = full_definition(EVENT)
    assert ADDED in text
    return text.replace(ADDED, "", 1)


def old_event_bytes(vertices: np.ndarray, triangles: np.ndarray) -> bytes:
    """A Segment event as the older installation serialized it (rosbags, from the old definition)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(old_definition(), "perch_interfaces/srv/msg/Segment_Event"))
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"](sec=7, nanosec=9)
    mesh = t["perch_interfaces/msg/TriangleMesh"](
        header=t["std_msgs/msg/Header"](stamp=stamp, frame_id="map"), vertices=vertices, triangles=triangles,
        vertex_colors=np.zeros(0, np.uint8), vertex_normals=np.zeros(0, np.float32), content_id="abc",
        viewpoints=np.zeros(0, np.float64))
    info = t["service_msgs/msg/ServiceEventInfo"](event_type=1, stamp=stamp, client_gid=np.arange(16, dtype=np.uint8),
                                                  sequence_number=42)
    event = t["perch_interfaces/srv/msg/Segment_Event"](
        info=info, request=[t["perch_interfaces/srv/msg/Segment_Request"](mesh=mesh)], response=[])
    return bytes(store.serialize_cdr(event, "perch_interfaces/srv/msg/Segment_Event"))


def test_an_event_recorded_without_request_id_reads_into_the_installed_class():
    from perch_interfaces.srv import Segment

    vertices = np.arange(9, dtype=np.float32)
    triangles = np.array([0, 1, 2], np.uint32)
    event = message_reader(EVENT, old_definition())(old_event_bytes(vertices, triangles))
    assert isinstance(event, Segment.Event)
    assert event.info.sequence_number == 42 and list(event.info.client_gid) == list(range(16))
    [request] = event.request
    assert request.request_id == ""   # the added field keeps its default
    np.testing.assert_array_equal(np.frombuffer(request.mesh.vertices, np.float32), vertices)
    assert list(request.mesh.triangles) == [0, 1, 2] and request.mesh.content_id == "abc"
    assert request.mesh.header.frame_id == "map" and request.mesh.header.stamp.nanosec == 9
    assert len(event.response) == 0


def test_stage_calls_read_an_old_recording(tmp_path):
    from mcap.writer import Writer

    from perch_operator.outputs.runfile import stage_calls

    path = tmp_path / "old.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="perch test")
        schema = writer.register_schema(name=EVENT, encoding="ros2msg", data=old_definition().encode())
        channel = writer.register_channel(topic="/perch/segment/_service_event", message_encoding="cdr",
                                          schema_id=schema)
        writer.add_message(channel_id=channel, log_time=1, publish_time=1, data=old_event_bytes(
            np.zeros(9, np.float32), np.array([0, 1, 2], np.uint32)))
        writer.finish()
    [call] = stage_calls(path)
    assert call.stage == "segment" and call.request.request_id == "" and len(call.request.mesh.triangles) == 3


def test_a_recording_with_the_installed_definition_reads_directly():
    from rclpy.serialization import serialize_message

    from perch_interfaces.srv import Segment

    event = Segment.Event()
    event.request.append(Segment.Request(request_id="caller/segment/1"))
    again = message_reader(EVENT, full_definition(EVENT))(serialize_message(event))
    assert again.request[0].request_id == "caller/segment/1"
