"""Why fewer cameras were placed than asked, in one sentence with the numbers."""

from __future__ import annotations

import numpy as np

from perch_common.types import PerchRegion

PACKING_GRID = 0.05  # m, grid of candidate drone positions on the regions for the packing count


def region_capacity(regions: list[PerchRegion], min_spacing: float) -> int:
    """Drones that fit on the regions at least `min_spacing` apart (a lower bound on the true maximum,
    see `packing`)."""
    from perch_common.polygons import to_shapely

    return len(packing([to_shapely(r.polygons) for r in regions], [r.frame for r in regions], min_spacing)[0])


def packing(shapes: list, frames: list, min_spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Drone positions at least `min_spacing` apart on the shapes (shapely, plane coordinates of
    `frames`): region index (M,) and world points (M,3) of the better of two packings of a 5 cm grid
    of region points and outline vertices, farthest-point and greedy along the points' principal
    axis (a lower bound on the true maximum; the greedy one is exact on strips)."""
    import shapely

    region, points = [], []
    for r, (shape, frame) in enumerate(zip(shapes, frames)):
        for poly in getattr(shape, "geoms", [shape]):
            if poly.is_empty or poly.geom_type != "Polygon":
                continue
            ring = np.asarray(poly.exterior.coords, float)
            lo, hi = ring.min(axis=0), ring.max(axis=0)
            u, v = np.meshgrid(np.arange(lo[0], hi[0] + PACKING_GRID, PACKING_GRID),
                               np.arange(lo[1], hi[1] + PACKING_GRID, PACKING_GRID))
            uv = np.column_stack([u.ravel(), v.ravel()])
            uv = np.concatenate([uv[shapely.intersects_xy(poly, uv[:, 0], uv[:, 1])], ring])
            region.append(np.full(len(uv), r))
            points.append(frame.to_world(uv))
    if not points:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    owner, cloud = np.concatenate(region), np.concatenate(points)
    picks = max((_farthest_point_packing(cloud, min_spacing), _greedy_packing(cloud, min_spacing)), key=len)
    return owner[picks], cloud[picks]


def _greedy_packing(cloud: np.ndarray, min_spacing: float) -> np.ndarray:
    """Points taken in order along the principal axis, each at least min_spacing from those taken
    (indices into cloud)."""
    centred = cloud - cloud.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    order = np.argsort(centred @ axis, kind="stable")
    ordered = cloud[order]
    # A point is taken when no earlier taken point is closer than min_spacing: walk to the next point
    # not yet blocked, take it, block its neighbours (one vectorised distance per drone, not per point).
    blocked = np.zeros(len(order), bool)
    taken: list[int] = []
    at = 0
    while at < len(order):
        taken.append(int(order[at]))
        blocked |= np.linalg.norm(ordered - ordered[at], axis=1) < min_spacing - 1e-9
        free = np.flatnonzero(~blocked[at + 1:])
        at = at + 1 + int(free[0]) if len(free) else len(order)
    return np.array(taken, np.int64)


def _farthest_point_packing(cloud: np.ndarray, min_spacing: float) -> np.ndarray:
    """Farthest-point sampling from the point farthest from the centroid, while min_spacing holds
    (indices into cloud)."""
    nearest = np.linalg.norm(cloud - cloud.mean(axis=0), axis=1)
    taken: list[int] = []
    while len(cloud) and nearest.max() >= (min_spacing - 1e-9 if taken else 0.0):
        chosen = int(np.argmax(nearest))
        distance = np.linalg.norm(cloud - cloud[chosen], axis=1)
        nearest = np.minimum(nearest, distance) if taken else distance
        taken.append(chosen)
    return np.array(taken, np.int64)


def shortfall_sentence(regions: list[PerchRegion], asked: int, placed: int, min_spacing: float,
                       reason: str = "", capacity: int | None = None) -> str:
    """'3 of 5 cameras: the only perch region, 0.80 m^2, holds 3 drones 1.0 m apart' ("" if none short)."""
    if placed >= asked:
        return ""
    head = f"{placed} of {asked} cameras"
    if not regions:
        return f"{head}: the filter left no perch region"
    area = sum(r.area for r in regions)
    if capacity is None:
        capacity = region_capacity(regions, min_spacing)
    capacity = max(capacity, placed)  # the placed drones are a packing too
    where = (f"the only perch region, {area:.2f} m^2," if len(regions) == 1 else
             f"the {len(regions)} perch regions, {area:.2f} m^2 in all (largest {max(r.area for r in regions):.2f} m^2),")
    holds = "holds" if len(regions) == 1 else "hold"
    if capacity <= placed:
        return f"{head}: {where} {holds} {capacity} drone(s) {min_spacing:g} m apart"
    return (f"{head}: {where} {holds} {capacity} drones {min_spacing:g} m apart, but no further perch adds "
            f"fitness ({reason or 'the rest see nothing new of the target'})")
