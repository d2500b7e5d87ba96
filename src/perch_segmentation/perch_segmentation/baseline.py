"""Open3D baselines on the same input, for side-by-side benchmark figures.

planar_patches: PointCloud.detect_planar_patches (Araujo & Oliveira's robust planar patches) on
the mesh vertices with normals. ransac: repeated segment_plane, peeling off the largest plane
until the remaining planes would be smaller than min_points. Faces get the plane of the majority
of their vertices, so the same face-area metrics apply.
"""

from __future__ import annotations

import time

import numpy as np

from perch_common.mesh import Mesh
from perch_common.types import PlaneFrame, Surface


def _point_cloud(mesh: Mesh):
    from perch_common.open3d_loader import open3d
    o3d = open3d()

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(mesh.vertices))
    normals = np.zeros_like(mesh.vertices)
    np.add.at(normals, mesh.faces.ravel(), np.repeat(mesh.face_normals() * mesh.face_areas()[:, None], 3, axis=0))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    pcd.normals = o3d.utility.Vector3dVector(np.divide(normals, length, out=np.zeros_like(normals), where=length > 0))
    return pcd


def _faces_from_vertices(mesh: Mesh, vertex_label: np.ndarray) -> np.ndarray:
    """Face label = label shared by at least two of its vertices, else -1."""
    a, b, c = (vertex_label[mesh.faces[:, k]] for k in range(3))
    return np.where((a == b) | (a == c), a, np.where(b == c, b, -1)).astype(np.int64)


def _surfaces(mesh: Mesh, face_labels: np.ndarray, normals: list[np.ndarray]) -> list[Surface]:
    areas, centroids = mesh.face_areas(), mesh.face_centroids()
    surfaces = []
    for k, normal in enumerate(normals):
        faces = np.flatnonzero(face_labels == k)
        w = areas[faces]
        origin = np.average(centroids[faces], axis=0, weights=w) if w.sum() > 0 else np.zeros(3)
        surfaces.append(Surface(k, PlaneFrame.from_normal(origin, normal), float(w.sum()), faces))
    return surfaces


def planar_patches(mesh: Mesh) -> tuple[float, np.ndarray, list[Surface]]:
    """(seconds, face labels, surfaces) of Open3D's planar patch detection."""
    pcd = _point_cloud(mesh)
    started = time.perf_counter()
    boxes = pcd.detect_planar_patches()
    vertex_label = np.full(mesh.num_vertices, -1, np.int64)
    boxes = sorted(boxes, key=lambda b: -float(np.prod(np.sort(b.extent)[1:])))  # largest patches claim first
    normals = []
    for k, box in enumerate(boxes):
        inside = np.asarray(box.get_point_indices_within_bounding_box(pcd.points), np.int64)
        inside = inside[vertex_label[inside] < 0]
        vertex_label[inside] = k
        normal = np.asarray(box.R)[:, int(np.argmin(box.extent))]
        normals.append(normal)
    seconds = time.perf_counter() - started
    face_labels = _faces_from_vertices(mesh, vertex_label)
    surfaces = _surfaces(mesh, face_labels, _orient(mesh, face_labels, normals))
    return seconds, face_labels, surfaces


def ransac(mesh: Mesh, distance: float = 0.02, min_points: int = 200, max_planes: int = 60,
           seed: int = 0) -> tuple[float, np.ndarray, list[Surface]]:
    """(seconds, face labels, surfaces) of sequential RANSAC plane extraction (seeded)."""
    from perch_common.open3d_loader import open3d
    o3d = open3d()

    o3d.utility.random.seed(seed)
    pcd = _point_cloud(mesh)
    started = time.perf_counter()
    remaining = np.arange(mesh.num_vertices)
    vertex_label = np.full(mesh.num_vertices, -1, np.int64)
    normals = []
    while len(remaining) >= min_points and len(normals) < max_planes:
        cloud = pcd.select_by_index(remaining)
        model, inliers = cloud.segment_plane(distance, 3, 200)
        if len(inliers) < min_points:
            break
        vertex_label[remaining[inliers]] = len(normals)
        normals.append(np.asarray(model[:3], np.float64) / np.linalg.norm(model[:3]))
        remaining = np.delete(remaining, inliers)
    seconds = time.perf_counter() - started
    face_labels = _faces_from_vertices(mesh, vertex_label)
    surfaces = _surfaces(mesh, face_labels, _orient(mesh, face_labels, normals))
    return seconds, face_labels, surfaces


def _orient(mesh: Mesh, face_labels: np.ndarray, normals: list[np.ndarray]) -> list[np.ndarray]:
    """Flip each plane normal to agree with the winding of the faces on it (as the stage does)."""
    weighted = mesh.face_normals() * mesh.face_areas()[:, None]
    out = []
    for k, normal in enumerate(normals):
        total = weighted[face_labels == k].sum(axis=0)
        out.append(-normal if float(total @ normal) < 0 else normal)
    return out
