"""Image, camera info and pose message conversions; depth unit checks; frame pairing."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from perch_common.errors import PerchError
from perch_reconstruction import images
from perch_reconstruction.frames import Intrinsics, check_depth
from perch_reconstruction.sync import FrameAssembler, PoseBuffer


def _msg(array, encoding, pad=0, bigendian=False):
    array = np.ascontiguousarray(array)
    h, w = array.shape[:2]
    rows = array.reshape(h, -1).view(np.uint8)
    data = np.concatenate([rows, np.zeros((h, pad), np.uint8)], axis=1).tobytes()
    return SimpleNamespace(height=h, width=w, encoding=encoding, is_bigendian=bigendian,
                           step=rows.shape[1] + pad, data=data)


def test_colour_encodings_and_row_padding():
    rgb = np.random.default_rng(0).integers(0, 255, (4, 5, 3), dtype=np.uint8)
    np.testing.assert_array_equal(images.color_from_msg(_msg(rgb, "rgb8", pad=3), "/c"), rgb)
    np.testing.assert_array_equal(images.color_from_msg(_msg(rgb[:, :, ::-1], "bgr8"), "/c"), rgb)
    rgba = np.concatenate([rgb, np.full((4, 5, 1), 255, np.uint8)], axis=2)
    np.testing.assert_array_equal(images.color_from_msg(_msg(rgba, "rgba8"), "/c"), rgb)


def test_depth_encodings():
    mm = np.array([[0, 1000], [2500, 65535]], np.uint16)
    np.testing.assert_allclose(images.depth_from_msg(_msg(mm, "16UC1", pad=2), "/d"), [[0, 1.0], [2.5, 0]])
    np.testing.assert_allclose(images.depth_from_msg(_msg(mm.byteswap(), "16UC1", bigendian=True), "/d"),
                               [[0, 1.0], [2.5, 0]])
    metres = np.array([[np.nan, 1.5], [-1.0, 3.25]], np.float32)
    np.testing.assert_allclose(images.depth_from_msg(_msg(metres, "32FC1"), "/d"), [[0, 1.5], [0, 3.25]])
    # explicit scale: 16-bit in units of 0.1 mm
    np.testing.assert_allclose(images.depth_from_msg(_msg(mm[:1], "16UC1"), "/d", depth_scale=1e-4), [[0, 0.1]])


def test_unknown_encodings_name_topic_and_encoding():
    with pytest.raises(PerchError, match=r"/cam/depth: unsupported depth encoding '8UC3'.*16UC1"):
        images.depth_from_msg(_msg(np.zeros((2, 2, 3), np.uint8), "8UC3"), "/cam/depth")
    with pytest.raises(PerchError, match=r"/cam/rgb: unsupported colour encoding 'yuv422'"):
        images.color_from_msg(_msg(np.zeros((2, 2, 2), np.uint8), "yuv422"), "/cam/rgb")


def test_truncated_image_data():
    msg = _msg(np.zeros((4, 4), np.uint16), "16UC1")
    msg.data = msg.data[:10]
    with pytest.raises(PerchError, match="does not hold 4x4 '16UC1' pixels"):
        images.depth_from_msg(msg, "/d")


def test_camera_info_round_trip_and_bad_info():
    intr = Intrinsics(640, 480, 585.0, 586.0, 320.0, 240.0)
    fields = images.camera_info_fields(intr, 5, "cam")
    as_msg = SimpleNamespace(**{k: v for k, v in fields.items()})
    assert images.intrinsics_from_camera_info(as_msg, "/info") == intr
    as_msg.k = [0.0] * 9
    with pytest.raises(PerchError, match="/info: camera info has no usable K"):
        images.intrinsics_from_camera_info(as_msg, "/info")


def test_pose_messages_round_trip():
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    pose[:3, 3] = [1, 2, 3]

    def ns(d):
        return SimpleNamespace(**{k: ns(v) if isinstance(v, dict) else v for k, v in d.items()})

    np.testing.assert_allclose(images.pose_from_msg(ns(images.pose_stamped_fields(pose, 7, "map"))), pose, atol=1e-12)
    odom = ns(images.odometry_fields(pose, 7, "map", "cam"))
    np.testing.assert_allclose(images.pose_from_msg(odom), pose, atol=1e-12)
    assert images.stamp_ns(odom) == 7


def test_depth_in_wrong_units_is_rejected():
    check_depth(np.full((10, 10), 2.5, np.float32), "/d")  # a room: fine
    with pytest.raises(PerchError, match=r"/d: median depth 2500 m.*check the depth units"):
        check_depth(np.full((10, 10), 2500.0, np.float32), "/d")  # millimetres read as metres
    with pytest.raises(PerchError, match="median depth 0.0025 m"):
        check_depth(np.full((10, 10), 0.0025, np.float32), "/d")  # metres scaled as millimetres


def test_assembler_pairs_by_stamp_and_counts_orphans():
    a = FrameAssembler(tolerance_ns=1000, max_pending=2)
    c, d = np.zeros((2, 2, 3), np.uint8), np.ones((2, 2), np.float32)
    assert a.add_color(10_000, c) is None
    frame = a.add_depth(10_500, d)
    assert frame is not None and frame.stamp_ns == 10_000 and frame.depth is d
    for stamp in (20_000, 30_000, 40_000):  # colour without depth: bounded, oldest discarded
        assert a.add_color(stamp, c) is None
    assert a.unpaired_dropped == 1
    assert a.add_depth(40_000, d).stamp_ns == 40_000
    assert a.unpaired_dropped == 2  # 30_000 can no longer pair


def test_pose_buffer_lookup_tolerance():
    b = PoseBuffer(capacity=3)
    for s in (0, 100, 200, 300):
        b.add(s, np.full((4, 4), s, float))
    assert len(b) == 3  # oldest dropped
    assert b.lookup(190, 20)[0, 0] == 200
    assert b.lookup(150, 20) is None
    assert b.lookup(0, 20) is None
