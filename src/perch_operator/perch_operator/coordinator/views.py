"""Each proposal's simulated camera view as sensor_msgs/Image + CameraInfo (what the camera would see).

Rendered by perch_placement's renderer from the mission's mesh at a reduced resolution (VIEW_SCALE of
the sensor), with the CameraInfo scaled to match, so Foxglove's or RViz's image panels show it.
"""

from __future__ import annotations

import numpy as np
from sensor_msgs.msg import CameraInfo, Image

VIEW_SCALE = 0.25  # of the sensor resolution: enough to judge a view, cheap to render on two cores


def image_msg(rgb: np.ndarray, frame_id: str, stamp) -> Image:
    """An (H,W,3) uint8 RGB array as an rgb8 Image."""
    rgb = np.ascontiguousarray(rgb, np.uint8)
    height, width = rgb.shape[:2]
    msg = Image(height=height, width=width, encoding="rgb8", is_bigendian=0, step=3 * width, data=rgb.tobytes())
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def camera_info_msg(camera, width: int, height: int, frame_id: str, stamp) -> CameraInfo:
    """The pinhole model of `camera` (CameraSpec) scaled to a width x height image."""
    sx, sy = width / float(camera.width), height / float(camera.height)
    fx, fy, cx, cy = camera.fx * sx, camera.fy * sy, camera.cx * sx, camera.cy * sy
    msg = CameraInfo(width=width, height=height, distortion_model="plumb_bob",
                     d=[float(v) for v in camera.distortion], k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                     r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], p=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    return msg


def render_proposal_view(mesh, scene, placement, camera, target) -> np.ndarray:
    """(H,W,3) uint8 RGB of the placement's camera (gravity-aligned placement, mesh and target)."""
    from perch_placement.render import render_view

    rgb, _depth = render_view(mesh, placement, camera, target, scale=VIEW_SCALE, scene=scene)
    rgb = np.asarray(rgb)
    return rgb if rgb.dtype == np.uint8 else (np.clip(rgb, 0, 1) * 255).astype(np.uint8)
