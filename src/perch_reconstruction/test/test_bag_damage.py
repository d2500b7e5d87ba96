"""Damaged bags: a chunk failing its CRC, a bag cut short, a bag missing only its summary. Each is read
as far as it goes, and bag info and the reconstruction say what was lost; nothing is read silently."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from perch_common.errors import PerchError
from perch_reconstruction.bag_read import bag_info, read_bag_frames

FRAMES = 40   # conftest's synthetic bag: 40 frames


def _messages(bag) -> int:
    return bag_info(bag)["messages"]


def _damaged(synthetic_bag, tmp_path, name: str, change) -> object:
    path = tmp_path / f"{name}.mcap"
    path.write_bytes(change(bytearray(synthetic_bag.read_bytes())))
    return path


def test_an_intact_bag_reports_no_damage(synthetic_bag):
    info = bag_info(synthetic_bag)
    assert info["problems"] == [] and not info["recovered"] and info["messages"] >= 4 * FRAMES
    assert read_bag_frames(synthetic_bag).damage == ""


def test_4_kb_corrupted_mid_file_loses_that_chunk_and_says_so(synthetic_bag, tmp_path):
    def corrupt(data: bytearray) -> bytes:
        middle = len(data) // 2
        data[middle:middle + 4096] = bytes(4096)
        return bytes(data)

    path = _damaged(synthetic_bag, tmp_path, "corrupt", corrupt)
    info = bag_info(path)
    assert info["recovered"] and 0 < info["messages"] < _messages(synthetic_bag)
    assert len(info["problems"]) == 1 and "is corrupt" in info["problems"][0] and "are lost" in info["problems"][0]
    bag = read_bag_frames(path)
    frames = list(bag.frames)
    assert 0 < len(frames) < FRAMES   # used to be "40 of 40 frames"
    lost = FRAMES - bag.frame_count
    assert lost > 0 and info["lost"]["/camera/color/image_raw"] <= lost   # counted from the bag's rosbag2 record
    assert bag.damage.startswith(f"damaged bag, read as far as it goes ({bag.frame_count} frame(s) recovered, "
                                 f"{lost} lost)")


def test_reconstruct_cli_warns_of_the_frames_a_damaged_bag_lost(synthetic_bag, tmp_path, capsys):
    """It used to print "N/N frames integrated" and exit 0 without a word of the lost chunk."""
    from perch_common.cli import main

    def corrupt(data: bytearray) -> bytes:
        middle = len(data) // 2
        data[middle:middle + 4096] = bytes(4096)
        return bytes(data)

    path = _damaged(synthetic_bag, tmp_path, "corrupt", corrupt)
    recovered = read_bag_frames(path).frame_count
    assert main(["reconstruct", "--bag", str(path), "-o", str(tmp_path / "mesh.ply")]) == 0
    captured = capsys.readouterr()
    warning = (f"perch: warning: damaged bag, read as far as it goes ({recovered} frame(s) recovered, "
               f"{FRAMES - recovered} lost): chunk at byte ")
    assert captured.err.splitlines()[-1].startswith(warning), captured.err
    assert f'"damage": "damaged bag, read as far as it goes ({recovered} frame(s) recovered' in captured.out
    assert main(["reconstruct", "--bag", str(synthetic_bag), "-o", str(tmp_path / "whole.ply")]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_chunk_failing_its_crc_is_detected(tmp_path):
    """An uncompressed chunk with one flipped byte decompresses fine; only its CRC tells."""
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "crc.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE, chunk_size=1000)
        writer.start(profile="", library="test")
        schema = writer.register_schema(name="raw", encoding="", data=b"")
        channel = writer.register_channel(topic="/data", message_encoding="raw", schema_id=schema)
        for i in range(20):
            writer.add_message(channel_id=channel, log_time=i, publish_time=i, data=bytes([i]) * 400)
        writer.finish()
    data = bytearray(path.read_bytes())
    at = data.index(bytes([10]) * 400)
    data[at + 100] ^= 0xFF
    path.write_bytes(bytes(data))
    info = bag_info(path)
    assert [p for p in info["problems"] if "fails its CRC check" in p], info["problems"]
    assert info["topics"]["/data"]["count"] < 20


def test_a_bag_missing_its_last_200_bytes_is_read_whole(synthetic_bag, tmp_path):
    path = _damaged(synthetic_bag, tmp_path, "tail", lambda data: bytes(data[:-200]))
    info = bag_info(path)
    assert info["messages"] == _messages(synthetic_bag) and info["recovered"]
    assert info["problems"] == ["the summary at the end of the file is cut short (every message is there; only "
                                "the index is lost)"]
    bag = read_bag_frames(path)
    assert len(list(bag.frames)) == FRAMES and "summary" in bag.damage


def test_a_bag_cut_in_half_gives_its_first_half(synthetic_bag, tmp_path):
    path = _damaged(synthetic_bag, tmp_path, "cut", lambda data: bytes(data[: len(data) // 2]))
    info = bag_info(path)
    assert info["recovered"] and "the file is cut short, with no summary" in info["problems"][0]
    frames = list(read_bag_frames(path).frames)
    assert 5 < len(frames) < FRAMES
    stamps = [f.stamp_ns for f in frames]
    assert stamps == sorted(stamps)


def test_a_bag_cut_before_any_message_is_refused(synthetic_bag, tmp_path):
    path = _damaged(synthetic_bag, tmp_path, "head", lambda data: bytes(data[:300]))
    with pytest.raises(PerchError, match=r"head.mcap: .*cut short.*recovered 0 message\(s\).*nothing to reconstruct"):
        read_bag_frames(path)


def test_bag_info_cli_prints_the_damage(synthetic_bag, tmp_path, capsys):
    from perch_common.cli import main

    path = _damaged(synthetic_bag, tmp_path, "tail", lambda data: bytes(data[:-200]))
    assert main(["bag", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "DAMAGED: the summary at the end of the file is cut short" in out and "Traceback" not in out
    np.testing.assert_equal(bag_info(path)["gravity"], [0.0, 0.0, -1.0])


def test_bag_play_says_a_bag_is_damaged_and_plays_what_it_holds(synthetic_bag, tmp_path, capsys):
    """Hunt 6: a bag cut short played 57 of 181 messages and exited 0 without a word (bag info said DAMAGED)."""
    from perch_common.cli import main

    path = _damaged(synthetic_bag, tmp_path, "cut", lambda data: bytes(data[: len(data) // 2]))
    assert main(["bag", "play", str(path), "--rate", "0", "--topics", "/camera/pose"]) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith("warning: damaged bag, played as far as it goes: ") and "cut short" in captured.err
    assert '"published": {"/camera/pose": ' in captured.out
    assert main(["bag", "play", str(synthetic_bag), "--rate", "0", "--topics", "/camera/pose"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_bag_folder_is_named_as_such(synthetic_bag, tmp_path):
    """Hunt 6: `bag play` on the folder `ros2 bag record` writes said "no such bag file"."""
    folder = tmp_path / "recorded"
    folder.mkdir()
    (folder / "recorded_0.mcap").write_bytes(synthetic_bag.read_bytes())
    with pytest.raises(PerchError, match=r"recorded: is a folder, not a bag file; give the \.mcap file in it "
                                         r"\(recorded_0\.mcap\)$"):
        bag_info(folder)


def _json_bag(path: Path, topics: dict[str, str]) -> Path:
    """An MCAP of JSON messages (another tool's, not a ROS 2 bag) on `topics` (topic -> type name)."""
    import json

    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        for topic, type_name in topics.items():
            schema = writer.register_schema(name=type_name, encoding="jsonschema", data=b'{"type":"object"}')
            channel = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema)
            for i in range(3):
                writer.add_message(channel_id=channel, log_time=i, publish_time=i, data=json.dumps({"i": i}).encode())
        writer.finish()
    return path


def test_a_bag_of_json_messages_is_refused_by_reconstruct(tmp_path):
    """Its JSON bytes were decoded as CDR: a TypeError traceback."""
    from perch_reconstruction.bag_read import read_bag_frames

    path = _json_bag(tmp_path / "json.mcap", {"/camera/color/image_raw": "sensor_msgs/msg/Image",
                                               "/camera/depth/image_raw": "sensor_msgs/msg/Image",
                                               "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo"})
    with pytest.raises(PerchError, match=r"json\.mcap: /camera/color/image_raw \(json\), /camera/depth/image_raw "
                                         r"\(json\), /camera/depth/camera_info \(json\) not CDR-encoded"):
        read_bag_frames(path)


def test_bag_play_refuses_topics_not_encoded_as_cdr(tmp_path, capsys):
    """Hunt 6: an MCAP of JSON messages was played: its JSON bytes went out as if they were CDR images."""
    from perch_common.cli import main

    path = _json_bag(tmp_path / "json.mcap", {"/camera/rgb": "sensor_msgs/msg/Image"})
    with pytest.raises(SystemExit) as exit_:
        main(["bag", "play", str(path), "--rate", "0"])
    assert exit_.value.code == 1
    captured = capsys.readouterr()
    assert "/camera/rgb (json) not CDR-encoded, as a ROS 2 bag's messages are" in captured.err
    assert "leave those topics out with --topics" in captured.err
    assert "published" not in captured.out and "Traceback" not in captured.err
