"""A quick look at a mesh: ray-cast image from above at an angle (vertex colours, lambert shade).

Used by the benchmark so a person can judge a reconstruction without a viewer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene


def render_mesh(mesh: Mesh, width: int = 800, height: int = 600, elevation_deg: float = 55.0,
                azimuth_deg: float = 30.0) -> np.ndarray:
    """(H,W,3) uint8 RGB view of a z-up mesh from above, framing its bounding box."""
    # Frame the bulk of the surface: a few stray fragments must not shrink the room to a dot.
    lo, hi = np.percentile(mesh.vertices, [2, 98], axis=0)
    center = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo)) * 0.8
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    back = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    fov = np.radians(50.0)
    eye = center + back * radius / np.sin(fov / 2)
    forward = -back
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    focal = 0.5 * width / np.tan(fov / 2)
    u, v = np.meshgrid(np.arange(width) - width / 2 + 0.5, np.arange(height) - height / 2 + 0.5)
    dirs = forward * focal + u[..., None] * right - v[..., None] * up
    dirs = (dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)).reshape(-1, 3)
    hits = RayScene(mesh).cast(np.broadcast_to(eye, dirs.shape), dirs)
    image = np.full((width * height, 3), 40, np.float64)
    hit = hits.hit
    if mesh.vertex_colors is not None:
        base = mesh.face_colors()[hits.face[hit]] * 255.0
    else:
        base = np.full((int(hit.sum()), 3), 200.0)
    shade = 0.35 + 0.65 * np.abs((hits.normal[hit] * dirs[hit]).sum(axis=1))
    image[hit] = base * shade[:, None]
    return np.clip(image, 0, 255).astype(np.uint8).reshape(height, width, 3)


def save_rendering(path: str | Path, mesh: Mesh, **kwargs) -> Path:
    """Render the mesh (render_mesh's options) to a PNG file; returns its path."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), render_mesh(mesh, **kwargs)[:, :, ::-1])
    return path
