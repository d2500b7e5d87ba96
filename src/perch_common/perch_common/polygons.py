"""Planar polygons with holes: outlines of face sets, conversions to and from shapely, raster outlines."""

from __future__ import annotations

import numpy as np

from perch_common.types import PlaneFrame


def cross2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z component of the cross product of 2D vectors (twice the signed triangle area)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def faces_outline(frame: PlaneFrame, triangles: np.ndarray, simplify: float = 0.0) -> list:
    """Outline of a set of (roughly coplanar) triangles in the frame's 2D coordinates.

    Returns polygons as lists of (K,2) rings (outer boundary first, then holes).
    """
    import shapely

    tris = np.asarray(triangles, np.float64)
    if len(tris) == 0:
        return []
    uv = frame.to_plane(tris.reshape(-1, 3)).reshape(-1, 3, 2)
    area2 = np.abs(cross2d(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]))
    uv = uv[area2 > 1e-12]
    if len(uv) == 0:
        return []
    pieces = shapely.polygons(uv)
    # Mesh triangles usually form a valid coverage (edge-matched, no overlap): 30x faster union.
    try:
        union = shapely.coverage_union_all(pieces)
        valid = union.is_valid
    except shapely.errors.GEOSException:  # noisy scans: triangles overlap once projected
        valid = False
    if not valid:
        union = shapely.union_all(pieces, grid_size=1e-6)
    if simplify > 0:
        union = union.simplify(simplify)
    return from_shapely(union)


def from_shapely(geometry) -> list:
    """Polygon/MultiPolygon (or a collection holding them) to lists of rings."""
    polygons = []
    for geom in getattr(geometry, "geoms", [geometry]):
        if geom.geom_type == "Polygon" and not geom.is_empty:
            rings = [np.asarray(geom.exterior.coords)[:-1]]
            rings += [np.asarray(r.coords)[:-1] for r in geom.interiors]
            polygons.append(rings)
        elif geom.geom_type in ("MultiPolygon", "GeometryCollection"):
            polygons.extend(from_shapely(geom))
    return polygons


def to_shapely(polygons: list):
    """Lists of rings to one shapely (Multi)Polygon."""
    import shapely

    parts = [shapely.Polygon(rings[0], rings[1:]) for rings in polygons if len(rings) and len(rings[0]) >= 3]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def polygons_area(polygons: list) -> float:
    """Total area of polygons with holes (m^2)."""
    return float(to_shapely(polygons).area)


MAX_RASTER_CELLS = 50_000_000   # raster_outline refuses larger images (50 MB of uint8)


def raster_outline(triangles: np.ndarray, cell: float, close_radius: float = 0.0, subpixel_bits: int = 0,
                   epsilon: float = 1.0) -> tuple[np.ndarray, float]:
    """Outer outline (K,2) and area (m^2) of the largest piece of the union of 2D triangles (N,3,2), holes ignored.

    Traced on a raster of `cell` metres (OpenCV fillPoly, findContours): the outline runs through
    the centres of the boundary pixels, so it lies within about a cell of the exact union's, and
    pieces closer than a cell join. close_radius: gaps narrower than this are closed first;
    subpixel_bits: corner precision below a cell (fillPoly's shift); epsilon: the Douglas-Peucker
    tolerance of the returned outline, in cells. Raises ValueError for more than MAX_RASTER_CELLS cells
    or no filled cell.
    """
    import cv2

    tris = np.asarray(triangles, np.float64).reshape(-1, 3, 2)
    pad = int(np.ceil(close_radius / cell)) + 2
    corners = tris.reshape(-1, 2)
    origin = corners.min(axis=0) - pad * cell
    cells = np.ceil((corners.max(axis=0) - origin) / cell).astype(int) + pad + 1
    if np.prod(cells) > MAX_RASTER_CELLS:
        raise ValueError(f"the triangles span {np.round(cells * cell, 1).tolist()} m; too large to outline at "
                         f"{cell} m cells")
    image = np.zeros((cells[1], cells[0]), np.uint8)
    scale = float(1 << subpixel_bits)
    pixels = np.round((tris - origin) / cell * scale).astype(np.int32)
    cv2.fillPoly(image, list(pixels), 255, shift=subpixel_bits)
    if close_radius > 0:
        radius = max(1, int(round(close_radius / cell)))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        image = cv2.morphologyEx(image, cv2.MORPH_CLOSE, kernel)
    contours, _ = cv2.findContours(image, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        raise ValueError("the triangles cover no cell")
    largest = max(contours, key=cv2.contourArea)
    outline = cv2.approxPolyDP(largest, epsilon, True).reshape(-1, 2)
    return origin + outline.astype(np.float64) * cell, float(cv2.contourArea(largest)) * cell * cell
