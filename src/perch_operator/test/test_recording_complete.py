"""A mission's recording is checked for every stage call the result says ran (issue 22, item 4): the
client waits for late events and says what is still missing, in its output and the recording."""

from types import SimpleNamespace

import pytest

CROP_EVENTS = "/perch/crop/_service_event"
SEGMENT_EVENTS = "/perch/segment/_service_event"


class GraphlessNode:
    """What MissionRecorder asks of its node, without a graph: no publishers known."""

    def resolve_topic_name(self, name):
        return "/" + name.lstrip("/")

    def get_namespace(self):
        return "/"

    def get_publishers_info_by_topic(self, topic):
        return []

    def create_publisher(self, *args, **kwargs):   # the recorder's observer marker (nothing is ever published)
        return None

    def destroy_publisher(self, publisher):
        pass


def event(srv, event_type: int, client: int, sequence: int) -> bytes:
    from rclpy.serialization import serialize_message

    message = srv.Event()
    message.info.event_type = event_type
    message.info.stamp.sec, message.info.stamp.nanosec = 1_700_000_000 + sequence, 123   # padding follows
    message.info.client_gid = [client] * 16
    message.info.sequence_number = sequence
    if event_type in (0, 1):
        message.request = [srv.Request()]
    else:
        message.response = [srv.Response(success=True)]
    return serialize_message(message)


@pytest.fixture
def recorder(tmp_path):
    from perch_operator.outputs.recorder import MissionRecorder

    made = MissionRecorder(GraphlessNode(), tmp_path / "run.mcap")
    yield made
    made.close()


def write(recorder, srv, topic, event_type, client, sequence):
    name = f"perch_interfaces/srv/{srv.__name__}_Event"
    recorder._write(topic, name, event(srv, event_type, client, sequence))


def test_calls_are_told_apart_by_client_and_sequence_and_halves_are_named(recorder):
    from perch_interfaces.srv import Crop, Segment

    write(recorder, Crop, CROP_EVENTS, 1, client=7, sequence=1)    # request received
    write(recorder, Crop, CROP_EVENTS, 2, client=7, sequence=1)    # reply sent: call 1 whole
    write(recorder, Crop, CROP_EVENTS, 2, client=8, sequence=1)    # another client's call: reply only
    write(recorder, Crop, CROP_EVENTS, 1, client=7, sequence=2)    # call 2: request only
    write(recorder, Segment, SEGMENT_EVENTS, 0, client=7, sequence=1)   # client-side events count too
    write(recorder, Segment, SEGMENT_EVENTS, 3, client=7, sequence=1)
    assert recorder.recorded_calls(CROP_EVENTS) == (1, ["request", "reply"])
    assert recorder.recorded_calls(SEGMENT_EVENTS) == (1, [])
    assert recorder.missing_calls({CROP_EVENTS: 1, SEGMENT_EVENTS: 1}, whole=False) == []
    assert recorder.missing_calls({CROP_EVENTS: 1, SEGMENT_EVENTS: 1}) == [
        "/perch/crop: 2 call(s) without their reply and request"]
    assert recorder.missing_calls({CROP_EVENTS: 2, SEGMENT_EVENTS: 2}, whole=False) == [
        "/perch/crop: 1 of 2 call(s) not recorded whole", "/perch/segment: 1 of 2 call(s) not recorded whole"]


def test_the_client_waits_for_late_events_then_names_what_is_missing(recorder, monkeypatch):
    from perch_interfaces.srv import Crop, Segment
    from perch_operator.cli import runner

    result = SimpleNamespace(success=True, stage_names=["crop", "segment", "confirm", "total"])
    watched = {CROP_EVENTS: "crop", SEGMENT_EVENTS: "segment"}
    write(recorder, Crop, CROP_EVENTS, 1, client=1, sequence=1)
    write(recorder, Crop, CROP_EVENTS, 2, client=1, sequence=1)
    write(recorder, Segment, SEGMENT_EVENTS, 1, client=1, sequence=2)
    late = [lambda: write(recorder, Segment, SEGMENT_EVENTS, 2, client=1, sequence=2)]
    spins = []

    def spin(node, seconds):   # the segment reply arrives at the first spin
        spins.append(seconds)
        if late:
            late.pop()()

    monkeypatch.setattr(runner, "spin_for", spin)
    assert runner.await_stage_events(None, recorder, result, watched, limit=60) == []
    assert len(spins) == 1   # waited for the event, then went on at once

    # The segment request never arrives: said so once the wait is over.
    lost = SimpleNamespace(success=True, stage_names=["crop", "segment", "segment", "total"])
    assert runner.await_stage_events(None, recorder, lost, watched, limit=0.3) == [
        "/perch/segment: 1 of 2 call(s) not recorded whole"]
    # Stages that did not run (a failed mission) are not expected; the failing stage is not listed.
    failed = SimpleNamespace(success=False, stage_names=["crop"])
    assert runner.await_stage_events(None, recorder, failed, watched, limit=0.3) == []


def test_a_missing_stage_call_is_in_the_report(tmp_path):
    from perch_operator.outputs.mission_data import MissionData
    from perch_operator.outputs.report import summary_rows

    data = MissionData()
    data.summary = {"message": "placed 2", "recording_missing": ["/perch/clean_mesh: 1 of 1 call(s) not recorded whole"]}
    rows = dict(summary_rows(data))
    assert rows["recording incomplete"] == "/perch/clean_mesh: 1 of 1 call(s) not recorded whole"
    data.summary = {"message": "placed 2", "recording_missing": []}
    assert "recording incomplete" not in dict(summary_rows(data))
