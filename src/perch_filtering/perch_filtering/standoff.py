"""Standoff clearance of many perch cells at once, settled mostly on a coarse grid of each surface.

A cell's standoff point lies `standoff` in front of its cell centre; the standoff points of one surface
form a lattice on a plane, one raster cell apart. The distance from a point to the mesh changes by at
most the distance the point moves (it is 1-Lipschitz), so the distance at a coarse node NODE_STEP cells
apart bounds it at every cell within NODE_STEP / 2 cells (both axes) of the node: where the bound
settles the question (clear by more than that slack, or blocked by more) the cell gets its answer
from the node; only the cells within the slack of the drone radius are measured exactly
(Open3D's closest points, as before). Same answers as measuring every cell, at a fraction of
the closest-point queries. The callers use it from proximity.LARGE_QUERY points on, where every
point was asked of Open3D's closest points: the open cells still are, so the answers are the same.
"""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import ray_scene
from perch_filtering.raster import SurfaceRaster

NODE_STEP = 8            # cells between coarse nodes (16 cm at 50 px/m)
FLOAT32_SLACK = 1e-3     # m: the closest-point scene works in float32 (~1e-5 m at 100 m); generous


def standoffs_clear(mesh: Mesh, surfaces: list[tuple[SurfaceRaster, np.ndarray, np.ndarray]], points: np.ndarray,
                    standoff: float, radius: float) -> np.ndarray:
    """(N,) True where no point of the mesh is within `radius` of each of `points`.

    `points` are, surface after surface, the standoff points of the cells of `mask` (row-major) that
    `asked` selects: raster.cell_world(mask)[asked] + standoff * normal; `surfaces` holds
    (raster, mask, asked) for each."""
    nodes, owner = [], []
    count = 0
    for raster, mask, asked in surfaces:
        rows, cols = np.nonzero(mask)
        rows, cols = rows[asked], cols[asked]
        half = NODE_STEP // 2
        node_r, node_c = (rows + half) // NODE_STEP, (cols + half) // NODE_STEP
        # Unique (row, col) nodes in row-major order, as one int key (np.unique of rows sorts slowly).
        width = int(node_c.max()) + 1 if len(node_c) else 1
        unique, inverse = np.unique(node_r * width + node_c, return_inverse=True)
        unique_r, unique_c = (unique // width) * NODE_STEP, (unique % width) * NODE_STEP
        uv = np.column_stack([raster.u0 + unique_c * raster.cell, raster.v0 + unique_r * raster.cell])
        owner.append(inverse.reshape(-1) + count)
        nodes.append(raster.frame.to_world(uv) + standoff * raster.frame.normal)
        count += len(uv)
    if not nodes:
        return np.ones(0, bool)
    node_distance = ray_scene(mesh).closest_points(np.concatenate(nodes))[2]
    cell = max((raster.cell for raster, _, _ in surfaces), default=0.0)
    slack = np.sqrt(2.0) * (NODE_STEP // 2) * cell + FLOAT32_SLACK
    distance = node_distance[np.concatenate(owner)]
    clear = distance - slack >= radius
    unsure = np.flatnonzero((distance + slack >= radius) & ~clear)
    # The points the bound leaves open get the query every point got before (Open3D's closest points,
    # whose scene is built by now): a k-d tree of the samples (clear_of_mesh's small-query path) would
    # cost a building more to build than the queries it answers.
    clear[unsure] = ray_scene(mesh).closest_points(points[unsure])[2] >= radius if len(unsure) else True
    return clear
