"""Kept raster cells back to polygons with holes (plane coordinates) and a triangulated 3D mesh."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.polygons import from_shapely
from perch_filtering.raster import SurfaceRaster


def mask_polygons(mask: np.ndarray, raster: SurfaceRaster) -> list:
    """One shapely polygon (with holes) per 8-connected component of kept cells.

    Outlines run around the squares of the outermost kept cells (each cell stands for its own
    square, as in the window kernel), so no kept cell's area is lost at a region's border.
    """
    import cv2
    import shapely

    if not mask.any():
        return []
    img = np.pad(mask.astype(np.uint8), 1)
    contours, hierarchy = cv2.findContours(img, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    hierarchy = hierarchy[0]
    polygons = []
    for i, (nxt, prev, child, parent) in enumerate(hierarchy):
        if parent != -1:
            continue
        outer = _to_uv(contours[i], raster)
        holes = []
        c = child
        while c != -1:
            holes.append(_to_uv(contours[c], raster))
            c = hierarchy[c][0]
        if len(outer) < 3:
            continue
        poly = shapely.Polygon(outer, [h for h in holes if len(h) >= 3])
        if not poly.is_valid:
            poly = shapely.make_valid(poly)
        # Mitred half-cell buffer: from the cell centres out to the cells' own squares.
        poly = poly.buffer(raster.cell / 2, join_style="mitre", mitre_limit=1.5)
        polygons.extend(g for g in getattr(poly, "geoms", [poly]) if g.geom_type == "Polygon" and g.area > 0)
    return polygons


def _to_uv(contour: np.ndarray, raster: SurfaceRaster) -> np.ndarray:
    pix = contour.reshape(-1, 2).astype(np.float64) - 1.0  # undo the padding
    return np.column_stack([raster.u0 + pix[:, 0] * raster.cell, raster.v0 + pix[:, 1] * raster.cell])


def triangulate(polygon, raster: SurfaceRaster, frame_id: str = "map") -> Mesh:
    """Ear-cut triangulation of one polygon with holes, lifted onto the plane in 3D."""
    import mapbox_earcut

    rings = from_shapely(polygon)[0]
    points = np.concatenate(rings).astype(np.float64)
    ends = np.cumsum([len(r) for r in rings]).astype(np.uint32)
    tri = mapbox_earcut.triangulate_float64(points, ends).astype(np.int64).reshape(-1, 3)
    vertices = raster.frame.to_world(points)
    # Wind every triangle so its normal is the frame normal (into free space).
    t = vertices[tri]
    flip = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) @ raster.frame.normal < 0
    tri[flip] = tri[flip][:, ::-1]
    normals = np.repeat(raster.frame.normal[None], len(vertices), axis=0)
    return Mesh(vertices, tri, vertex_normals=normals, frame_id=frame_id)
