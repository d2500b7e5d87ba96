"""A visualization_msgs/Marker with large point and colour arrays, serialized without a Python
object per element.

rclpy builds a message's `points` and `colors` from one geometry_msgs/Point and one
std_msgs/ColorRGBA object per element: a building's scan marker (125k-153k corners) took ~0.85 s of CPU
holding the interpreter, twice a mission, beside the stages. Here the marker is serialized
by rclpy without its two arrays, and the arrays' bytes (CDR: a count, then packed float64 x, y, z
and float32 r, g, b, a) are written between the fields before them and those after them. The fields
after `colors` hold no 8-byte number, so their bytes do not depend on where they start (always on
a 4-byte boundary after the colours). The result reads back as the whole message rclpy would
write (the test compares them; padding bytes are not compared: rclpy leaves them unset), and is
published as it is (`Publisher.publish(bytes)`).
"""

from __future__ import annotations

import struct

import numpy as np
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker

CDR_LITTLE_ENDIAN = b"\x00\x01"   # encapsulation kind of the first two bytes
ENCAPSULATION = 4                 # bytes before the CDR body


def serialized_marker(marker: Marker, points: np.ndarray, colors: np.ndarray | None = None) -> bytes:
    """`marker` with `points` ((N,3) metres) and `colors` ((N,4) RGBA in 0..1, or None for none) as
    the serialized message; the marker's own `points` and `colors` are ignored and left empty."""
    points = np.ascontiguousarray(points, "<f8").reshape(-1, 3)
    colors = np.ascontiguousarray(colors if colors is not None else np.zeros((0, 4)), "<f4").reshape(-1, 4)
    marker.points, marker.colors = [], []
    empty = serialize_message(marker)
    if empty[:2] != CDR_LITTLE_ENDIAN:
        raise RuntimeError(f"unexpected CDR encapsulation {empty[:4].hex()}: cannot splice a marker's arrays")
    at = _points_count_offset(marker) + ENCAPSULATION
    padding = -(at + 4 - ENCAPSULATION) % 8 if len(points) else 0  # the first float64 on an 8-byte boundary
    return b"".join([empty[:at], struct.pack("<I", len(points)), bytes(padding), points.tobytes(),
                     struct.pack("<I", len(colors)), colors.tobytes(), empty[at + 8:]])


def _points_count_offset(marker: Marker) -> int:
    """Where the points' count lies in the CDR body of `marker` (classic CDR: each number on a
    boundary of its own size, counted from the body's start; a string is a count, its bytes and a NUL)."""
    def string(at: int, text: str) -> int:
        return _aligned(at, 4) + 4 + len(text.encode()) + 1

    at = 8                                     # header.stamp: int32 sec, uint32 nanosec
    at = string(at, marker.header.frame_id)
    at = string(at, marker.ns)
    at = _aligned(at, 4) + 3 * 4               # id, type, action
    at = _aligned(at, 8) + 7 * 8 + 3 * 8       # pose (position, orientation), scale
    at = _aligned(at, 4) + 4 * 4 + 2 * 4 + 1   # color, lifetime, frame_locked
    return _aligned(at, 4)


def _aligned(at: int, size: int) -> int:
    return at + (-at) % size
