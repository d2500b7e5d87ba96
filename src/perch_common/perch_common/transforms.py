"""Rotations and the up axis (gravity) handling."""

from __future__ import annotations

import numpy as np

# Imported up front: a lazy import here once stalled a node's first pose callback for ~1 s.
from scipy.spatial.transform import Rotation


def quaternion_from_matrix(r: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a 3x3 rotation matrix."""
    return Rotation.from_matrix(np.asarray(r, np.float64)[:3, :3]).as_quat()


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of an (x, y, z, w) quaternion; a zero quaternion is the identity."""
    q = np.asarray(q, np.float64)
    if not np.any(q):
        return np.eye(3)
    return Rotation.from_quat(q).as_matrix()


def pose_to_matrix(pose) -> np.ndarray:
    """4x4 of anything shaped like geometry_msgs/Pose (position.x.., orientation.x..w), e.g. a
    message decoded from a bag without the message packages."""
    o, p = pose.orientation, pose.position
    out = np.eye(4)
    out[:3, :3] = matrix_from_quaternion(np.array([o.x, o.y, o.z, o.w], np.float64))
    out[:3, 3] = [p.x, p.y, p.z]
    return out


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit direction a onto unit direction b."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-12:  # opposite: turn half a circle about any perpendicular axis
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


UP_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
           "+z": (0, 0, 1), "-z": (0, 0, -1)}


def parse_up_axis(text: str) -> np.ndarray:
    """'+z', '-y', ... or 'x y z' components as a unit vector."""
    key = text.strip().lower()
    if key in UP_AXES:
        return np.array(UP_AXES[key], np.float64)
    if key in ("x", "y", "z"):
        return np.array(UP_AXES["+" + key], np.float64)
    try:
        v = np.array([float(t) for t in key.replace(",", " ").split()], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-9:
        raise ValueError(f"up axis '{text}': use +x, -x, +y, -y, +z, -z or three numbers")
    return v / np.linalg.norm(v)


def estimate_up(normals: np.ndarray, areas: np.ndarray, bins: int = 2000,
                max_samples: int = 8000, centroids: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Up direction of a room scan from its dominant planes.

    Floors, ceilings and walls share three orthogonal axes: the densest normal axis and the densest
    axis orthogonal to it give all three. Up is the one along which the scan is thinnest (rooms
    are wider than tall; needs `centroids`, else the densest axis is taken), signed so that most
    horizontal area (floor, furniture tops; ceilings are often incomplete) lies in the lower half.
    Without centroids the sign makes most of that area face up. Returns (up, confidence): the
    share of area whose normals lie within 10 degrees of +-up.
    """
    normals = np.asarray(normals, np.float64)
    areas = np.asarray(areas, np.float64)
    ok = np.linalg.norm(normals, axis=1) > 0.5
    normals, areas = normals[ok], areas[ok]
    centroids = None if centroids is None else np.asarray(centroids, np.float64)[ok]
    if len(normals) == 0 or areas.sum() <= 0:
        return np.array([0.0, 0.0, 1.0]), 0.0
    cos10 = np.cos(np.radians(10))
    # Area-weighted sample (seeded, so the answer is deterministic) for the direction search.
    sample = np.arange(len(normals))
    weights = areas
    if len(normals) > max_samples:
        sample = np.random.default_rng(0).choice(len(normals), max_samples, p=areas / areas.sum())
        weights = np.ones(max_samples)
    fib = _fibonacci_sphere(bins)
    fib = fib[fib[:, 2] >= 0]
    first = fib[int(np.argmax(weights @ (np.abs(normals[sample] @ fib.T) > cos10)))]
    across = fib[np.abs(fib @ first) < np.sin(np.radians(3))]
    second = across[int(np.argmax(weights @ (np.abs(normals[sample] @ across.T) > cos10)))]
    second = second - (second @ first) * first
    axes = [first, second / np.linalg.norm(second), np.cross(first, second / np.linalg.norm(second))]
    if centroids is not None:
        extents = [np.ptp(centroids @ a) for a in axes]
        axis = axes[int(np.argmin(extents))]
    else:
        axis = axes[0]
    near = np.abs(normals @ axis) > cos10
    signs = np.sign(normals[near] @ axis)
    axis = (normals[near] * signs[:, None] * areas[near, None]).sum(axis=0)
    axis /= np.linalg.norm(axis)
    if centroids is not None:
        height = centroids[near] @ axis
        middle = (height.min() + height.max()) / 2
        lower = areas[near][height < middle].sum()
        upper = areas[near][height >= middle].sum()
        flip = upper > lower
    else:
        flip = areas[near][normals[near] @ axis < 0].sum() > areas[near][normals[near] @ axis > 0].sum()
    return (-axis if flip else axis), float(areas[near].sum() / areas.sum())


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def estimate_mesh_up(mesh) -> tuple[np.ndarray, float]:
    """estimate_up for a perch_common.mesh.Mesh (uses face positions for axis and sign)."""
    return estimate_up(mesh.face_normals(), mesh.face_areas(), centroids=mesh.face_centroids())


def resolve_up_axis(text: str, mesh=None) -> np.ndarray:
    """The configured up axis; "auto" estimates it from the mesh's dominant planes."""
    if text.strip().lower() == "auto":
        if mesh is None:
            raise ValueError("up axis 'auto' needs a mesh to estimate it from")
        return estimate_mesh_up(mesh)[0]
    return parse_up_axis(text)
