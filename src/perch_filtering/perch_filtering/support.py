"""Support on the scan: how much of a perch window has scanned surface on the perch plane, and how flat.

One ray per raster cell, cast against the mesh along the inverted normal from `tolerance` in front
of the plane: a hit within `tolerance` of the plane is scanned surface under that cell. Window
shares and RMS distances are box sums of those per-cell values (holes, edges and ragged geometry
leave cells unsupported).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.raycast import RayScene
from perch_filtering.raster import SurfaceRaster


@dataclass
class WindowSupport:
    """Per window centre: share of the window with scanned surface, RMS distance of that surface."""

    share: np.ndarray  # float32 (rows, cols)
    rms: np.ndarray    # float32 (rows, cols), m; inf where nothing is supported


def cell_support(scene: RayScene, raster: SurfaceRaster, cells: np.ndarray,
                 tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """For the cells in `cells`: whether scanned surface lies within `tolerance` of the plane, and its
    signed distance to the plane (0 where unsupported)."""
    supported = np.zeros(raster.shape, bool)
    distance = np.zeros(raster.shape, np.float32)
    if not cells.any():
        return supported, distance
    normal = raster.frame.normal
    start = 1.001 * tolerance + 1e-4
    origins = raster.cell_world(cells) + start * normal
    hits = scene.cast(origins, np.repeat(-normal[None], len(origins), axis=0))
    ok = hits.hit & (hits.distance <= start + tolerance)
    supported[cells] = ok
    distance[cells] = np.where(ok, start - hits.distance, 0.0)
    return supported, distance


def window_support(supported: np.ndarray, distance: np.ndarray, kernel: np.ndarray) -> WindowSupport:
    """Share of each window (kernel centred on the cell) that is supported and the RMS distance there."""
    import cv2

    k = kernel.astype(np.float32)
    count = cv2.filter2D(supported.astype(np.float32), -1, k, borderType=cv2.BORDER_CONSTANT)
    squares = cv2.filter2D((distance * distance * supported).astype(np.float32), -1, k,
                           borderType=cv2.BORDER_CONSTANT)
    share = count / float(k.sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        rms = np.where(count > 0.5, np.sqrt(np.maximum(squares, 0.0) / np.maximum(count, 1.0)), np.inf)
    return WindowSupport(share.astype(np.float32), rms.astype(np.float32))
