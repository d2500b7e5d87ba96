"""The camera simulator: projection with Brown-Conrady distortion, visibility and stereo covariance.

Batched over B cameras and N points. Information matrices are packed as 6 components
(perch_common.symmetric) and scaled by ||C_max|| so that a point's score (perch_placement.fitness)
is 1 - 1/lambda_min.
"""

from __future__ import annotations

import numpy as np

from perch_common.symmetric import SYM6
from perch_placement.config import CameraSpec


def distort(x: np.ndarray, y: np.ndarray, coeffs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalised image coordinates through Brown-Conrady; also whether the radial map is monotonic there.

    Beyond the radius where r*(1 + k1 r^2 + k2 r^4 + k3 r^6) turns back, far off-axis points would
    fold back into the image; they are not imaged, so `valid` marks where d(r_d)/dr > 0.
    """
    k1, k2, p1, p2, k3 = (float(c) for c in coeffs)
    if k1 == k2 == p1 == p2 == k3 == 0.0:
        return x, y, np.ones(np.shape(x), bool)
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    valid = 1 + r2 * (3 * k1 + r2 * (5 * k2 + r2 * 7 * k3)) > 0
    return xd, yd, valid


def undistort(xd: np.ndarray, yd: np.ndarray, coeffs, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Invert `distort` by fixed-point iteration (as OpenCV's undistortPoints)."""
    k1, k2, p1, p2, k3 = (float(c) for c in coeffs)
    x, y = xd.copy(), yd.copy()
    if not (k1 or k2 or p1 or p2 or k3):   # no distortion (the default camera): the iteration is the identity
        return x, y
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return x, y


def project(camera: CameraSpec, points_cam: np.ndarray, zoom=1.0) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) points in the optical frame to (..., 2) pixels and a mask: in front, imaged, on the sensor."""
    z = points_cam[..., 2]
    front = z > 1e-9
    safe_z = np.where(front, z, 1.0)
    xd, yd, monotonic = distort(points_cam[..., 0] / safe_z, points_cam[..., 1] / safe_z, camera.distortion)
    zoom = np.asarray(zoom, np.float64)
    u = camera.fx * zoom * xd + camera.cx
    v = camera.fy * zoom * yd + camera.cy
    on_sensor = (u >= 0) & (u <= camera.width) & (v >= 0) & (v <= camera.height)
    return np.stack([u, v], axis=-1), front & monotonic & on_sensor


def on_sensor(camera: CameraSpec, points_cam: np.ndarray) -> np.ndarray:
    """In front, imaged and on the sensor (unzoomed); without distortion this needs no division:
    0 <= fx x + cx z <= W z and likewise for y."""
    if any(float(c) != 0.0 for c in camera.distortion):
        return project(camera, points_cam)[1]
    x, y, z = points_cam[..., 0], points_cam[..., 1], points_cam[..., 2]
    u = camera.fx * x + camera.cx * z
    v = camera.fy * y + camera.cy * z
    return (z > 1e-9) & (u >= 0) & (u <= camera.width * z) & (v >= 0) & (v <= camera.height * z)


def in_view(camera: CameraSpec, positions: np.ndarray, rotations: np.ndarray, points: np.ndarray,
            zoom: np.ndarray | float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Everything but occlusion, for B cameras (positions (B,3), world-from-camera rotations (B,3,3))
    and N points: returns mask (B,N), distances (B,N) and unit directions camera->point (B,N,3)."""
    delta = points[None, :, :] - positions[:, None, :]
    distance = np.linalg.norm(delta, axis=-1)
    unit = delta / np.maximum(distance, 1e-12)[..., None]
    local = np.matmul(delta, rotations)  # R^T (p - t), row-vector form
    zoom = np.broadcast_to(np.asarray(zoom, np.float64), (len(positions),))
    _, mask = project(camera, local, zoom[:, None])
    r_max = np.minimum(camera.max_range,
                       camera.focal * zoom * camera.min_feature_size / camera.min_feature_pixels)
    mask &= (distance >= camera.min_range) & (distance <= r_max[:, None])
    return mask, distance, unit


def sigmas(camera: CameraSpec, distance: np.ndarray, zoom=1.0) -> tuple[np.ndarray, np.ndarray]:
    """Stereo error across the ray sigma_xy = d e / f and along it sigma_z = d^2 e / (f b) (metres)."""
    f = camera.focal * np.asarray(zoom, np.float64)
    e = camera.subpixel_error
    return distance * e / f, distance ** 2 * e / (f * camera.baseline)


def max_covariance_norm(camera: CameraSpec) -> float:
    """||C_max||: spectral norm of one unzoomed camera's covariance at R_max."""
    s_xy, s_z = sigmas(camera, np.float64(camera.max_distance()))
    return float(max(s_xy, s_z) ** 2)


def covariance(camera: CameraSpec, distance: np.ndarray, unit: np.ndarray, zoom=1.0) -> np.ndarray:
    """(..., 3, 3) world covariance sigma_xy^2 I + (sigma_z^2 - sigma_xy^2) u u^T."""
    s_xy, s_z = sigmas(camera, distance, zoom)
    outer = unit[..., :, None] * unit[..., None, :]
    return (s_xy ** 2)[..., None, None] * np.eye(3) + (s_z ** 2 - s_xy ** 2)[..., None, None] * outer


def information6(camera: CameraSpec, distance: np.ndarray, unit: np.ndarray, zoom=1.0,
                 scale: float | None = None) -> np.ndarray:
    """(..., 6) information C^-1 = a I + (c - a) u u^T with a = 1/sigma_xy^2, c = 1/sigma_z^2,
    multiplied by `scale` (default ||C_max||, so lambda_min >= 1 within R_max)."""
    scale = max_covariance_norm(camera) if scale is None else scale
    s_xy, s_z = sigmas(camera, np.maximum(distance, 1e-9), zoom)
    a = scale / s_xy ** 2
    c = scale / s_z ** 2
    out = np.empty(distance.shape + (6,))
    for k, (i, j) in enumerate(SYM6):
        out[..., k] = (c - a) * unit[..., i] * unit[..., j] + (a if i == j else 0.0)
    return out
