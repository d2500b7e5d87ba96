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


def _segment_recording(path, calls: int, chunk_size: int, big_requests: bool, finish: bool,
                       drop_replies: tuple = ()) -> None:
    """`calls` segment calls in uncompressed chunks, with the rosbag2 record (counts) when `finish`;
    big requests make a chunk close right after a request, so a cut loses that call's reply only."""
    from mcap.writer import CompressionType, Writer
    from rclpy.serialization import serialize_message

    from perch_common.ros import bag_format
    from perch_common.ros.msgdefs import full_definition
    from perch_interfaces.srv import Segment

    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.NONE)
        writer.start(profile="ros2", library="perch test")
        schema = writer.register_schema(name="perch_interfaces/srv/Segment_Event", encoding="ros2msg",
                                        data=full_definition("perch_interfaces/srv/Segment_Event").encode())
        channel = writer.register_channel(topic=SERVICE_EVENT, message_encoding="cdr", schema_id=schema)
        for call in range(calls):
            for event_type in (1, 2):
                event = Segment.Event()
                event.info.event_type, event.info.sequence_number = event_type, call + 1
                if event_type == 1:
                    event.request.append(Segment.Request(request_id=f"c/{call}" + " " * (900 * big_requests)))
                else:
                    event.response.append(Segment.Response(success=True, message=f"{call} surfaces" + " " * 900))
                stamp = 1_000_000 * (2 * call + event_type)
                writer.add_message(channel_id=channel, log_time=stamp, publish_time=stamp,
                                   data=serialize_message(event))
        if finish:
            bag_format.add_rosbag2_metadata(writer, [bag_format.TopicRecord(SERVICE_EVENT, "perch_interfaces/srv/"
                                                                            "Segment_Event", count=2 * calls)],
                                            1_000_000, 2_000_000 * calls + 2_000_000, path.name)
            writer.finish()


def _answer_like_the_recording(monkeypatch, calls: list[int]):
    """The live segment service answers the recorded `calls`, in order, as recorded."""
    import perch_common.ros.testing as testing
    from perch_interfaces.srv import Segment

    replies = iter(calls)

    def answer(node, srv_type, name, request, timeout, wait):
        return Segment.Response(success=True, message=f"{next(replies)} surfaces" + " " * 900)

    monkeypatch.setattr(testing, "call_service", answer)


def test_replay_check_of_calls_lost_to_a_corrupt_chunk_is_not_a_plain_pass(tmp_path, monkeypatch):
    """It used to end "replay check passed: 4 stage call(s) match the recording" (exit 0)."""
    from perch_operator.cli.replay import replay, summary_line

    path = tmp_path / "run.mcap"
    _segment_recording(path, CALLS, chunk_size=2000, big_requests=False, finish=True)
    data = bytearray(path.read_bytes())
    data[data.index(b"2 surfaces") + 1] ^= 0xFF   # calls 2 and 3 share the chunk: its CRC fails
    path.write_bytes(bytes(data))
    _answer_like_the_recording(monkeypatch, [0, 1, 4, 5])
    out = io.StringIO()
    outcomes = replay(None, path, check=True, out=out)
    assert [o.call.key[2] for o in outcomes] == [1, 2, 5, 6]   # sequence numbers: calls 2 and 3 lost
    assert all(o.ok and not o.unchecked for o in outcomes)
    assert out.getvalue().splitlines()[0].endswith("2 stage call(s) lost to the damage (segment x2)")
    assert summary_line(outcomes, True) == ("replay check INCOMPLETE, damaged recording: passed for the 4 stage "
                                            "call(s) that survived; 2 stage call(s) lost to the damage (segment x2): "
                                            "those were not checked")


def test_replay_check_of_a_reply_cut_off_is_not_a_difference(tmp_path, monkeypatch):
    """A recording cut (perch plan killed) after a request but before its reply: it used to fail with
    "FAIL segment #2 no recorded reply to compare with"."""
    from perch_operator.cli.replay import replay, summary_line

    path = tmp_path / "killed.mcap"
    # Chunks close on a request: [req 0, reply 0, req 1] is written, the chunk holding reply 1 never is.
    _segment_recording(path, 2, chunk_size=2000, big_requests=True, finish=False)
    _answer_like_the_recording(monkeypatch, [0, 1])
    out = io.StringIO()
    outcomes = replay(None, path, check=True, out=out)
    assert [o.ok for o in outcomes] == [True, True] and outcomes[1].call.response is None
    assert "FAIL" not in out.getvalue()
    assert out.getvalue().splitlines()[-1].startswith("LOST  segment #2     replied in ")
    line = summary_line(outcomes, True)
    assert "FAILED" not in line and line.startswith("replay check INCOMPLETE, damaged recording: passed for the 1 "
                                                    "stage call(s) that survived; 1 not compared, their recorded "
                                                    "replies lost (segment #2); an unknown number")


def test_a_killed_recording_with_no_request_left_names_the_damage_first(tmp_path):
    """It used to blame the stage services' introspection parameters."""
    from perch_common.errors import PerchError
    from perch_operator.cli.replay import replay

    path = tmp_path / "killed.mcap"
    _segment_recording(path, 1, chunk_size=100_000, big_requests=False, finish=False)   # its one chunk never written
    with pytest.raises(PerchError) as caught:
        replay(None, path, check=True, out=io.StringIO())
    assert str(caught.value).startswith(f"{path}: the recording has no summary")
    assert caught.value.args[0].endswith("no stage request survived the damage, so nothing to replay (a recorder "
                                         "killed with SIGKILL loses the chunk it had open)")
    assert "introspection" not in str(caught.value)


def test_a_recording_that_lost_only_its_index_passes_plainly(tmp_path, monkeypatch):
    from perch_operator.cli.replay import replay, summary_line

    path = tmp_path / "run.mcap"
    _segment_recording(path, CALLS, chunk_size=2000, big_requests=False, finish=True)
    path.write_bytes(path.read_bytes()[:-200])
    _answer_like_the_recording(monkeypatch, list(range(CALLS)))
    outcomes = replay(None, path, check=True, out=io.StringIO())
    assert summary_line(outcomes, True) == ("replay check passed: 6 stage call(s) match the recording (damaged "
                                            "recording: no stage call was lost)")


def test_replay_check_exits_nonzero_when_a_damaged_recording_left_calls_unchecked():
    from perch_operator.cli.commands import check_exit_code

    assert check_exit_code("replay check passed: 5 stage call(s) match the recording") == 0
    assert check_exit_code("replay check passed: 5 stage call(s) match the recording (damaged recording: "
                           "no stage call was lost)") == 0
    assert check_exit_code("replay check INCOMPLETE, damaged recording: passed for the 3 stage call(s) that "
                           "survived; 2 stage call(s) lost to the damage (crop, segment)") == 3
    assert check_exit_code("replay check FAILED: 1 of 3 stage call(s) differ") == 1
