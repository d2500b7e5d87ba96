"""Step 3: clusters to Surfaces (PCA frame, area, colour, RMS, faces, outline with holes)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from perch_common.mesh import Mesh
from perch_common.types import PlaneFrame, Surface, SurfaceClass
from perch_segmentation import stats as st
from perch_segmentation.outline import outline


def frames_of(table: np.ndarray, centre: np.ndarray) -> tuple[list[PlaneFrame], np.ndarray]:
    """PCA frame per cluster (origin = area-weighted centroid, u = main axis, normal by winding
    majority, v = normal x u) and the RMS distance of each cluster's surface to its plane."""
    centroid, values, vectors = st.pca_frames(table)
    normals = st.oriented_normals(table, vectors)
    cross = st.cross(normals, vectors[:, :, 2])  # np.cross's floats, one call for all clusters
    frames = []
    for k in range(len(table)):
        v = cross[k]
        frames.append(PlaneFrame(centroid[k] + centre, vectors[k, :, 2], v / np.linalg.norm(v), normals[k]))
    return frames, np.sqrt(values[:, 0])


def faces_by_label(face_labels: np.ndarray, count: int) -> list[np.ndarray]:
    """The face indices of each label 0..count-1."""
    order = np.argsort(face_labels, kind="stable")
    bounds = np.searchsorted(face_labels[order], np.arange(count + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(count)]


def build_surfaces(mesh: Mesh, triangles: np.ndarray, centre: np.ndarray, table: np.ndarray,
                   face_labels: np.ndarray, cell: float, simplify: float, threads: int = 2) -> list[Surface]:
    """Surfaces for the clusters in `table` (row k = label k); triangles are centred on `centre`."""
    frames, rms = frames_of(table, centre)
    area = table[:, st.AREA]
    color = table[:, st.RGB] / np.maximum(area, 1e-18)[:, None]
    groups = faces_by_label(face_labels, len(table))

    def outline_of(k: int) -> list:
        frame = frames[k]
        centred = PlaneFrame(frame.origin - centre, frame.axis_u, frame.axis_v, frame.normal)
        uv = centred.to_plane(triangles[groups[k]].reshape(-1, 3)).reshape(-1, 3, 2)
        return outline(uv, cell, simplify)

    # OpenCV, shapely and numpy release the GIL: outlines of different surfaces run in parallel.
    order = np.argsort(-area)  # largest first, so the long ones start early
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        boundaries = dict(zip(order.tolist(), pool.map(outline_of, order.tolist())))
    return [Surface(id=k, frame=frames[k], area=float(area[k]), face_indices=groups[k].astype(np.int64),
                    surface_class=SurfaceClass.UNKNOWN, rms_distance=float(rms[k]), mean_color=color[k].copy(),
                    boundary=boundaries[k])
            for k in range(len(table))]
