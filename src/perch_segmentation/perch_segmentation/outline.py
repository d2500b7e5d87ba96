"""Outlines of surfaces (polygons with holes in plane coordinates) by rasterising their faces.

A shapely union of every triangle costs seconds for a large surface, and noisy scans have
fold-overs that are no valid coverage (make_valid then costs more than the whole segmentation).
Instead each surface's faces are sampled onto a grid of `cell` metres in its plane, the mask is
closed against pinholes, and OpenCV traces outer contours and holes. The outline is accurate to
about one cell, which the simplification tolerance exceeds anyway.
"""

from __future__ import annotations

import numpy as np

_MAX_PIXELS = 4096  # per side; coarser cells for huge surfaces keep memory bounded
_FILL_ABOVE = 4.0  # cells; triangles with longer edges are scan-converted instead of sampled


def _barycentric_grid(k: int) -> np.ndarray:
    """(M,3) barycentric weights of a triangular grid with spacing 1/(k+1) of the edges, inset
    by a third of the spacing so no sample lies on an edge (it would mark the pixel beyond)."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = i + j <= k
    i, j = i[keep], j[keep]
    return np.stack([k - i - j + 1.0 / 3.0, i + 1.0 / 3.0, j + 1.0 / 3.0], axis=1) / (k + 1.0)


def _edge_lengths(tri: np.ndarray) -> np.ndarray:
    """(F,3) lengths of the edges tri[:, k] - tri[:, k-1] of (F,3,2) triangles; the same floats as
    np.linalg.norm of np.roll(tri, 1, axis=1) differences without its per-call overhead."""
    x, y = tri[:, :, 0], tri[:, :, 1]
    dx = x - x[:, [2, 0, 1]]
    dy = y - y[:, [2, 0, 1]]
    return np.sqrt(dx * dx + dy * dy)


def _sample_triangles(uv: np.ndarray, spacing: float, edge: np.ndarray | None = None) -> np.ndarray:
    """Points covering each (F,3,2) triangle no more than `spacing` apart along its edges
    (`edge`: each triangle's longest edge, when the caller has it)."""
    if edge is None:
        edge = _edge_lengths(uv).max(axis=1)
    levels = np.maximum(0, np.ceil(edge / spacing) - 1).astype(np.int64)
    parts = [np.zeros((0, 2))]
    for k in np.unique(levels):
        w = _barycentric_grid(int(k))
        tri = uv[levels == k]
        parts.append((tri[:, None, 0] * w[None, :, 0, None] + tri[:, None, 1] * w[None, :, 1, None]
                      + tri[:, None, 2] * w[None, :, 2, None]).reshape(-1, 2))
    return np.concatenate(parts)


def _shrink(tri: np.ndarray, inset: float, edges: np.ndarray | None = None) -> np.ndarray:
    """(F,3,2) triangles with every edge moved inwards by `inset` (scaled about the incentre);
    `edges`: their _edge_lengths, when the caller has them."""
    edges = _edge_lengths(tri) if edges is None else edges
    lengths = edges[:, [2, 0, 1]]  # the edge opposite each corner
    perimeter = lengths.sum(axis=1)
    incentre = (lengths[:, :, None] * tri).sum(axis=1) / perimeter[:, None]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    radius = area2 / perimeter
    scale = np.clip((radius - inset) / np.maximum(radius, 1e-12), 0.0, 1.0)
    return incentre[:, None] + (tri - incentre[:, None]) * scale[:, None, None]


def outline(uv: np.ndarray, cell: float, simplify: float) -> list:
    """Polygons (lists of (K,2) rings, outer first) covered by the (F,3,2) plane triangles uv."""
    import cv2
    import shapely

    from perch_common.mesh import column_bounds
    from perch_common.polygons import from_shapely

    if len(uv) == 0:
        return []
    bounds = column_bounds(uv.reshape(-1, 2))
    low = bounds[0]
    extent = bounds[1] - low
    cell = max(cell, float(extent.max()) / (_MAX_PIXELS - 4))
    origin = low - 2 * cell
    size = np.ceil(extent / cell).astype(np.int64) + 5
    mask = np.zeros((int(size[1]), int(size[0])), np.uint8)
    grid = (uv - origin) / cell
    edges = _edge_lengths(grid)
    edge = edges.max(axis=1)
    large = edge > _FILL_ABOVE
    if large.any():
        # Large triangles are filled (scanline, even-odd: overlaps could cancel, hence also the
        # samples of their corners and centres below); small ones are sampled densely. OpenCV
        # fills edges inclusively: pulling every edge in by half a pixel keeps outlines unbiased.
        inner = _shrink(grid[large], 0.5, edges[large])
        cv2.fillPoly(mask, np.round((inner - 0.5) * 16).astype(np.int32), 1, cv2.LINE_8, 4)
        corners = np.concatenate([inner.reshape(-1, 2), inner.mean(axis=1)])
    else:
        corners = np.zeros((0, 2))
    small = ~large
    points = np.concatenate([_sample_triangles(grid[small], 0.7, edge[small]), corners])
    pixel = np.floor(points).astype(np.int64)
    mask[pixel[:, 1], pixel[:, 0]] = 1
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return []
    epsilon = max(simplify / cell, 0.5)
    rings = [cv2.approxPolyDP(c, epsilon, True).reshape(-1, 2) * cell + origin + 0.5 * cell for c in contours]
    parents = hierarchy[0][:, 3]
    polygons = _polygons(rings, parents)
    if not polygons:
        return []
    shape = shapely.MultiPolygon(polygons) if len(polygons) > 1 else polygons[0]
    if not shapely.is_valid(shape):  # make_valid gives a valid shape back unchanged, at 8x is_valid's cost
        shape = shapely.make_valid(shape)
    # Contours run through the centres of the outermost cells: grow by half a cell to the true edge.
    shape = shape.buffer(0.5 * cell, join_style="mitre")
    return from_shapely(shape)


def _polygons(rings: list, parents: np.ndarray) -> list:
    """shapely Polygons of the outer rings (parent -1) with their holes (rings of at least 3 points),
    built in two vectorised calls instead of a Polygon (and a LinearRing per ring) each."""
    import shapely

    outer = [k for k in np.flatnonzero(parents < 0) if len(rings[k]) >= 3]
    if not outer:
        return []
    holes_of: dict[int, list[int]] = {k: [] for k in outer}
    for h in np.flatnonzero(parents >= 0):
        if parents[h] in holes_of and len(rings[h]) >= 3:
            holes_of[parents[h]].append(h)
    order = [r for k in outer for r in [k] + holes_of[k]]   # each polygon's shell, then its holes
    polygon_of = np.repeat(np.arange(len(outer)), [1 + len(holes_of[k]) for k in outer])
    ring_of = np.repeat(np.arange(len(order)), [len(rings[r]) for r in order])
    linear = shapely.linearrings(np.concatenate([rings[r] for r in order]), indices=ring_of)
    return list(shapely.polygons(linear, indices=polygon_of))
