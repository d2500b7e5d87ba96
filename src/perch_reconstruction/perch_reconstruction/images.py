"""sensor_msgs Image/CompressedImage/CameraInfo and pose messages <-> numpy.

Works on anything with the message's attributes (rclpy messages, mcap-decoded messages), so the
bag reader and the live node share one implementation; builders return plain dicts the MCAP
encoder accepts. No rclpy import.
"""

from __future__ import annotations

import numpy as np

from perch_common.errors import PerchError
from perch_common.timing import time_ns
from perch_common.transforms import pose_to_matrix, quaternion_from_matrix
from perch_reconstruction.frames import Intrinsics

COLOR_ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False), "bgra8": (4, True),
                   "mono8": (1, False)}
DEPTH_ENCODINGS = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}


def _raw(msg, topic: str, channels: int, dtype) -> np.ndarray:
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    data = bytes(msg.data) if not isinstance(msg.data, (bytes, bytearray, memoryview)) else msg.data
    if height == 0 or width == 0:
        raise PerchError(f"{topic}: empty image ({width}x{height})")
    if step < width * channels * itemsize or len(data) < step * height:
        raise PerchError(f"{topic}: image data of {len(data)} bytes does not hold {width}x{height} "
                         f"'{msg.encoding}' pixels with row step {step}")
    rows = np.frombuffer(data, np.uint8, count=step * height).reshape(height, step)
    pixels = rows[:, :width * channels * itemsize].copy().view(dtype)
    if msg.is_bigendian and itemsize > 1:
        pixels = pixels.byteswap()
    return pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)


def color_from_msg(msg, topic: str) -> np.ndarray:
    """(H,W,3) uint8 RGB from sensor_msgs/Image or CompressedImage."""
    if hasattr(msg, "format"):
        return _decode_compressed(msg, topic, color=True)
    encoding = str(msg.encoding)
    if encoding not in COLOR_ENCODINGS:
        raise PerchError(f"{topic}: unsupported colour encoding '{encoding}' "
                         f"(use one of {', '.join(COLOR_ENCODINGS)})")
    channels, bgr = COLOR_ENCODINGS[encoding]
    pixels = _raw(msg, topic, channels, np.uint8)
    if channels == 1:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    pixels = pixels[:, :, :3]
    return np.ascontiguousarray(pixels[:, :, ::-1] if bgr else pixels)


def depth_from_msg(msg, topic: str, depth_scale: float = 0.0) -> np.ndarray:
    """(H,W) float32 metres, 0 where invalid. 16UC1 is millimetres unless depth_scale (m per unit) > 0."""
    if hasattr(msg, "format"):
        raw = _decode_compressed(msg, topic, color=False)
        return (raw.astype(np.float32) * np.float32(depth_scale or 0.001))
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise PerchError(f"{topic}: unsupported depth encoding '{encoding}' "
                         "(use 16UC1 in millimetres or 32FC1 in metres)")
    raw = _raw(msg, topic, 1, DEPTH_ENCODINGS[encoding])
    if raw.dtype == np.uint16:
        depth = raw.astype(np.float32) * np.float32(depth_scale or 0.001)
        depth[raw == 65535] = 0  # Kinect's invalid marker
        return depth
    depth = raw.astype(np.float32) * np.float32(depth_scale or 1.0)
    depth[~np.isfinite(depth) | (depth < 0)] = 0
    return depth


def _decode_compressed(msg, topic: str, color: bool) -> np.ndarray:
    import cv2

    buffer = np.frombuffer(bytes(msg.data), np.uint8)
    if "compresseddepth" in str(msg.format).lower():
        # compressed_depth_image_transport prefixes its PNG with a 12-byte header (format, quantisation)
        buffer = buffer[12:]
    image = cv2.imdecode(buffer, cv2.IMREAD_COLOR if color else cv2.IMREAD_UNCHANGED) if len(buffer) else None
    if image is None:
        raise PerchError(f"{topic}: compressed image in format '{msg.format}' cannot be decoded")
    if color:
        return np.ascontiguousarray(image[:, :, ::-1])
    if image.dtype != np.uint16 or image.ndim != 2:
        raise PerchError(f"{topic}: compressed depth must be a 16-bit single-channel PNG, got {image.dtype} "
                         f"with {1 if image.ndim == 2 else image.shape[2]} channels")
    return image


def intrinsics_from_camera_info(msg, topic: str) -> Intrinsics:
    """Intrinsics of a sensor_msgs/CameraInfo (PerchError naming the topic when unusable)."""
    k = np.asarray(msg.k, np.float64)
    if k.shape != (9,) or k[0] <= 0 or k[4] <= 0 or int(msg.width) == 0 or int(msg.height) == 0:
        raise PerchError(f"{topic}: camera info has no usable K ({k.tolist()}) or size "
                         f"{msg.width}x{msg.height}; publish calibrated intrinsics")
    return Intrinsics.from_matrix(k, int(msg.width), int(msg.height))


def pose_from_msg(msg) -> np.ndarray:
    """4x4 world-from-camera of a PoseStamped or Odometry."""
    return pose_to_matrix(msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose)


def stamp_ns(msg) -> int:
    """A message header's stamp in nanoseconds."""
    return time_ns(msg.header.stamp)


# --- builders (dicts for the MCAP encoder) -----------------------------------------------------

def header(stamp: int, frame_id: str) -> dict:
    """std_msgs/Header fields for a bag record."""
    return {"stamp": {"sec": stamp // 1_000_000_000, "nanosec": stamp % 1_000_000_000}, "frame_id": frame_id}


def image_fields(array: np.ndarray, encoding: str, stamp: int, frame_id: str) -> dict:
    """sensor_msgs/Image fields of an array."""
    array = np.ascontiguousarray(array)
    height, width = array.shape[:2]
    return {"header": header(stamp, frame_id), "height": height, "width": width, "encoding": encoding,
            "is_bigendian": 0, "step": array.nbytes // height, "data": array.tobytes()}


def compressed_fields(array: np.ndarray, fmt: str, stamp: int, frame_id: str) -> dict:
    """sensor_msgs/CompressedImage fields of an array (JPEG colour or PNG depth)."""
    import cv2

    if fmt == "jpeg":
        ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(array[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    else:
        ok, buffer = cv2.imencode(".png", array if array.ndim == 2 else np.ascontiguousarray(array[:, :, ::-1]))
    if not ok:
        raise PerchError(f"cannot encode image as {fmt}")
    return {"header": header(stamp, frame_id), "format": fmt, "data": buffer.tobytes()}


def camera_info_fields(intr: Intrinsics, stamp: int, frame_id: str) -> dict:
    """sensor_msgs/CameraInfo fields of the intrinsics."""
    k = intr.matrix()
    p = np.zeros((3, 4))
    p[:, :3] = k
    return {"header": header(stamp, frame_id), "height": intr.height, "width": intr.width,
            "distortion_model": "plumb_bob", "d": [0.0] * 5, "k": k.ravel().tolist(),
            "r": np.eye(3).ravel().tolist(), "p": p.ravel().tolist(), "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}


def _pose_dict(matrix: np.ndarray) -> dict:
    q = quaternion_from_matrix(matrix[:3, :3])
    t = matrix[:3, 3]
    return {"position": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
            "orientation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}


def transform_fields(matrix: np.ndarray, stamp: int, frame_id: str, child_frame_id: str) -> dict:
    """geometry_msgs/TransformStamped fields of a 4x4 parent-from-child transform."""
    pose = _pose_dict(matrix)
    return {"header": header(stamp, frame_id), "child_frame_id": child_frame_id,
            "transform": {"translation": pose["position"], "rotation": pose["orientation"]}}


def pose_stamped_fields(matrix: np.ndarray, stamp: int, frame_id: str) -> dict:
    """geometry_msgs/PoseStamped fields of a 4x4 pose."""
    return {"header": header(stamp, frame_id), "pose": _pose_dict(matrix)}


def odometry_fields(matrix: np.ndarray, stamp: int, frame_id: str, child_frame_id: str) -> dict:
    """nav_msgs/Odometry fields of a 4x4 pose (zero twist)."""
    zero3 = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {"header": header(stamp, frame_id), "child_frame_id": child_frame_id,
            "pose": {"pose": _pose_dict(matrix), "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": zero3, "angular": dict(zero3)}, "covariance": [0.0] * 36}}
