"""A recording's stage calls come back in the order they were made, whatever order the recorder heard
their events in: events of different topics (different writers, often different processes) reach it
in no set order, and a large request can arrive after a small one made later."""

from __future__ import annotations

import numpy as np

SECOND = 1_000_000_000


def _event(srv_type, event_type: int, made_ns: int, sequence: int, request=None, response=None):
    event = srv_type.Event()
    event.info.event_type, event.info.sequence_number = event_type, sequence
    event.info.stamp.sec, event.info.stamp.nanosec = divmod(made_ns, SECOND)
    if request is not None:
        event.request.append(request)
    if response is not None:
        event.response.append(response)
    return event


def _write(path, messages) -> None:
    """`messages`: (topic, srv type name, event, log time ns), written in the order given."""
    from mcap.writer import Writer
    from rclpy.serialization import serialize_message

    from perch_common.ros.msgdefs import full_definition

    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="ros2", library="perch test")
        channels: dict[str, int] = {}
        for topic, type_name, event, log_ns in messages:
            if topic not in channels:
                schema = writer.register_schema(name=f"{type_name}_Event", encoding="ros2msg",
                                                data=full_definition(f"{type_name}_Event").encode())
                channels[topic] = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
            writer.add_message(channel_id=channels[topic], log_time=log_ns, publish_time=log_ns,
                               data=serialize_message(event))
        writer.finish()


def test_calls_are_ordered_by_when_they_were_made_not_when_the_recorder_heard_them(tmp_path):
    from perch_interfaces.msg import TriangleMesh
    from perch_interfaces.srv import Crop, Segment
    from perch_operator.outputs.runfile import stage_calls

    cropped = TriangleMesh(content_id="cropped", vertices=np.arange(9, dtype=np.float64).tolist(),
                           triangles=[0, 1, 2])
    crop_topic, segment_topic = "/perch/crop/_service_event", "/perch/segment/_service_event"
    crop, segment = "perch_interfaces/srv/Crop", "perch_interfaces/srv/Segment"
    t = 100 * SECOND
    # Made: crop request (t), crop reply with the arrays (t+1 s), segment request naming that mesh by
    # id (t+2 s). Heard: the small segment request first, the big crop request last.
    path = tmp_path / "run.mcap"
    _write(path, [
        (segment_topic, segment, _event(Segment, 1, t + 2 * SECOND, 1,
                                        request=Segment.Request(mesh=TriangleMesh(content_id="cropped"))), t + 3 * SECOND),
        (crop_topic, crop, _event(Crop, 2, t + SECOND, 1, response=Crop.Response(success=True, mesh=cropped)),
         t + 4 * SECOND),
        (segment_topic, segment, _event(Segment, 2, t + 5 * SECOND, 1, response=Segment.Response(success=True)),
         t + 5 * SECOND),
        (crop_topic, crop, _event(Crop, 1, t, 1, request=Crop.Request(request_id="c/1")), t + 6 * SECOND),
    ])
    calls = stage_calls(path)
    assert [c.stage for c in calls] == ["crop", "segment"]
    assert [c.stamp_ns for c in calls] == [t, t + 2 * SECOND]
    assert calls[0].request.request_id == "c/1" and calls[1].response.success
    # The segment request's id-only mesh got the arrays the crop reply carried before it.
    assert list(calls[1].request.mesh.triangles) == [0, 1, 2]


def test_the_callers_stamp_orders_a_call_before_the_servers(tmp_path):
    """A call heard from both sides (client REQUEST_SENT, server REQUEST_RECEIVED) is placed by the
    caller's clock: all of one mission's calls come from one caller, while servers may run on hosts
    whose clocks differ."""
    from perch_interfaces.srv import Segment
    from perch_operator.outputs.runfile import stage_calls

    topic, segment = "/perch/segment/_service_event", "perch_interfaces/srv/Segment"
    t = 100 * SECOND
    path = tmp_path / "run.mcap"
    _write(path, [
        # call 1: server clock 10 s ahead of the caller's
        (topic, segment, _event(Segment, 1, t + 10 * SECOND, 1, request=Segment.Request(request_id="first")), t),
        (topic, segment, _event(Segment, 0, t, 1, request=Segment.Request(request_id="first")), t + 1),
        # call 2: made by the caller 1 s later
        (topic, segment, _event(Segment, 0, t + SECOND, 2, request=Segment.Request(request_id="second")), t + 2),
    ])
    calls = stage_calls(path)
    assert [c.request.request_id for c in calls] == ["first", "second"]
    assert [c.stamp_ns for c in calls] == [t, t + SECOND]
