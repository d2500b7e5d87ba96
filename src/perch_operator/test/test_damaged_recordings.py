"""A recording its recorder never closed (SIGKILL) or that lost its tail still replays: what is there is
read, and the replay says what was lost; no traceback."""

from __future__ import annotations

import io

import pytest

SERVICE_EVENT = "/perch/segment/_service_event"
CALLS = 6


def _recording(stream, finish: bool) -> None:
    """CALLS segment calls (request and reply events) in small chunks; `finish=False` stops like a
    recorder killed mid-mission (no summary, the last chunk never written)."""
    from mcap.writer import Writer
    from rclpy.serialization import serialize_message

    from perch_common.ros.msgdefs import full_definition
    from perch_interfaces.srv import Segment

    writer = Writer(stream, chunk_size=2000)
    writer.start(profile="ros2", library="perch test")
    schema = writer.register_schema(name="perch_interfaces/srv/Segment_Event", encoding="ros2msg",
                                    data=full_definition("perch_interfaces/srv/Segment_Event").encode())
    channel = writer.register_channel(topic=SERVICE_EVENT, message_encoding="cdr", schema_id=schema)
    for call in range(CALLS):
        for event_type in (1, 2):   # request received, response sent
            event = Segment.Event()
            event.info.event_type, event.info.sequence_number = event_type, call + 1
            if event_type == 1:
                event.request.append(Segment.Request(request_id=f"c/{call}"))
            else:
                event.response.append(Segment.Response(success=True, message=f"{call} surfaces" + " " * 900))
            stamp = 1_000_000 * (2 * call + event_type)
            writer.add_message(channel_id=channel, log_time=stamp, publish_time=stamp, data=serialize_message(event))
    if finish:
        writer.finish()


@pytest.fixture
def recordings(tmp_path):
    whole = tmp_path / "run.mcap"
    with open(whole, "wb") as stream:
        _recording(stream, finish=True)
    killed = tmp_path / "killed.mcap"
    buffer = io.BytesIO()
    _recording(buffer, finish=False)
    killed.write_bytes(buffer.getvalue()[:-100])   # killed while writing its last chunk
    tail = tmp_path / "tail.mcap"
    tail.write_bytes(whole.read_bytes()[:-200])
    return whole, killed, tail


def test_stage_calls_of_a_killed_or_cut_recording(recordings):
    from perch_common.mcap_read import scan_mcap
    from perch_operator.outputs.runfile import channel_counts, stage_calls

    whole, killed, tail = recordings
    assert len(stage_calls(whole)) == CALLS and scan_mcap(whole).damage() == ""
    assert len(stage_calls(tail)) == CALLS
    assert channel_counts(tail) == {SERVICE_EVENT: 2 * CALLS}
    # The events of the chunk being written when the recorder died are lost: the last reply at least.
    calls = stage_calls(killed)
    assert sum(channel_counts(killed).values()) < 2 * CALLS
    assert [c.request.request_id for c in calls] == [f"c/{i}" for i in range(len(calls))]
    assert 0 < len(calls) < CALLS and all(c.response is not None for c in calls[:-1])
    assert "no summary" in scan_mcap(killed).damage()


def test_replay_of_a_killed_recording_warns_and_replays_what_is_there(recordings, monkeypatch):
    import perch_common.ros.testing as testing
    from perch_interfaces.srv import Segment
    from perch_operator.cli.replay import replay, summary_line

    _, killed, _ = recordings
    sent = []

    def answer(node, srv_type, name, request, timeout, wait):
        sent.append(request.request_id)
        return Segment.Response(success=True, message=f"{len(sent) - 1} surfaces" + " " * 900)

    monkeypatch.setattr(testing, "call_service", answer)
    out = io.StringIO()
    outcomes = replay(None, killed, check=True, out=out)
    text = out.getvalue()
    assert text.startswith("perch: warning: damaged recording, replaying what could be read: ")
    assert "no summary" in text.splitlines()[0]
    assert 0 < len(outcomes) < CALLS and all(o.ok for o in outcomes[:-1])
    assert outcomes[-1].ok or outcomes[-1].error == "no recorded reply to compare with"
    assert sent == ["" for _ in outcomes]   # replayed without the recorded request ids
    assert summary_line(outcomes, True)
