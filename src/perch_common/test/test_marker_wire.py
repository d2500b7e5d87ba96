"""serialized_marker writes the whole marker as rclpy would, without an object per element."""

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker

from perch_common.ros.marker_wire import serialized_marker


def marker(frame_id: str, text: str) -> Marker:
    m = Marker(type=Marker.TRIANGLE_LIST, ns="scan", id=7, action=Marker.ADD, text=text, mesh_resource="pkg://x")
    m.header.frame_id, m.header.stamp = frame_id, Time(sec=12, nanosec=345)
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = 1.0
    m.color = ColorRGBA(r=0.5, g=0.25, b=1.0, a=1.0)
    m.uv_coordinates = []
    return m


# Frame ids of several lengths move the arrays across 4- and 8-byte boundaries (padding or none).
@pytest.mark.parametrize("frame_id", ["m", "ma", "map", "odom", "input_frame"])
@pytest.mark.parametrize("count, coloured", [(0, False), (1, True), (5, False), (999, True)])
def test_the_bytes_read_back_as_the_whole_marker(frame_id, count, coloured):
    rng = np.random.default_rng(count)
    points = rng.normal(size=(count, 3)) * 10
    colors = rng.random((count, 4)) if coloured else None
    whole = marker(frame_id, "after the arrays")
    whole.points = [Point(x=x, y=y, z=z) for x, y, z in points.tolist()]
    if coloured:
        whole.colors = [ColorRGBA(r=r, g=g, b=b, a=a) for r, g, b, a in colors.tolist()]
    spliced = serialized_marker(marker(frame_id, "after the arrays"), points, colors)
    assert len(spliced) == len(serialize_message(whole))  # the same layout (padding bytes are left unset)
    back = deserialize_message(spliced, Marker)
    assert back == deserialize_message(serialize_message(whole), Marker)  # colours as float32, as sent
    np.testing.assert_array_equal(np.array([(p.x, p.y, p.z) for p in back.points]).reshape(-1, 3), points)
    assert (back.header.frame_id, back.text, back.mesh_resource) == (frame_id, "after the arrays", "pkg://x")
