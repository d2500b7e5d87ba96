"""A picture of a segmentation for people to judge: faces coloured by surface, dollhouse view.

Orthographic views from above at an angle, with back faces culled so that walls and ceilings
facing away from the camera do not hide the room (a scan's normals point into the room).
Painter's algorithm with OpenCV; no display or GPU needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh


def label_colors(face_labels: np.ndarray, seed: int = 7) -> np.ndarray:
    """(F,3) uint8: a distinct colour per surface, grey for faces on none."""
    import cv2

    count = max(int(face_labels.max()) + 1 if len(face_labels) else 0, 1)
    # Golden-ratio hues keep neighbouring ids (similar sizes) far apart in colour.
    hue = (np.arange(count) * 0.618034 % 1.0 * 180).astype(np.uint8)
    rng = np.random.default_rng(seed)
    hsv = np.stack([hue, rng.integers(120, 256, count), rng.integers(150, 256, count)], 1).astype(np.uint8)
    palette = cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0]
    colors = np.full((len(face_labels), 3), 90, np.uint8)
    labelled = face_labels >= 0
    colors[labelled] = palette[face_labels[labelled]]
    return colors


def _view(mesh: Mesh, colors: np.ndarray, up: np.ndarray, azimuth: float, elevation: float,
          size: int) -> np.ndarray:
    import cv2

    up = up / np.linalg.norm(up)
    side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    ahead = np.cross(up, side)
    horizontal = np.cos(azimuth) * side + np.sin(azimuth) * ahead
    view_dir = -np.cos(elevation) * horizontal - np.sin(elevation) * up  # camera looks along this
    right = np.cross(view_dir, up)
    right /= np.linalg.norm(right)
    screen_up = np.cross(right, view_dir)
    normals = mesh.face_normals()
    visible = normals @ view_dir < 0
    centred = mesh.vertices - mesh.vertices.mean(axis=0)
    xy = np.stack([centred @ right, -(centred @ screen_up)], axis=1)
    depth = mesh.face_centroids() @ view_dir
    low, high = xy.min(axis=0), xy.max(axis=0)
    scale = (size - 20) / max(float((high - low).max()), 1e-9)
    pixels = np.round(((xy - low) * scale + 10) * 16).astype(np.int32)
    image = np.full((size, size, 3), 255, np.uint8)
    shade = 0.55 + 0.45 * np.clip(-(normals @ view_dir), 0, 1)
    lit = np.clip(colors.astype(np.float64) * shade[:, None], 0, 255).astype(np.uint8)
    order = np.flatnonzero(visible)[np.argsort(-depth[visible])]  # far to near
    tri = pixels[mesh.faces[order]]
    for points, color in zip(tri, lit[order][:, ::-1].tolist()):
        cv2.fillConvexPoly(image, points, color, cv2.LINE_8, 4)
    return image


def render_segmentation(mesh: Mesh, face_labels: np.ndarray, path: str | Path, up=(0.0, 0.0, 1.0),
                        size: int = 900) -> Path:
    """Write a PNG with two dollhouse views of the mesh coloured by surface."""
    import cv2

    colors = label_colors(face_labels)
    up = np.asarray(up, np.float64)
    views = [_view(mesh, colors, up, a, np.radians(55.0), size) for a in (np.radians(35.0), np.radians(215.0))]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(views, axis=1))
    return path
