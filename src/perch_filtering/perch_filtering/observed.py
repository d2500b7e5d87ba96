"""Observed versus unknown space: which part of a perch's approach prism and fall corridor the scan
actually saw.

A reconstructed mesh carries the camera views it was built from (Mesh.viewpoints): then a point is
observed when some camera saw through it, i.e. measured a surface behind it within its range with
nothing before it (perch_common.viewpoints.seen_free); the cameras' evidence replaces the escape rule
below (a room the cameras saw only half of encloses its other half too, unseen).

A bare mesh carries no camera poses, so "observed" is what the scan encloses: a point is observed when at
most `enclosed_escape_share` of the rays cast from it in ESCAPE_DIRECTIONS fixed directions leave
the model without a hit. Inside a scanned room almost every ray ends on a wall, floor or ceiling (a
doorway or window opening lets a minority out; a room without ceiling lets out less than half); in
front of an isolated wall fragment at the scan's edge, with nothing scanned below or in front of it,
most rays escape. Space behind a scan's edge is therefore unknown, and a drone may neither approach
nor fall through it. A fall volume also needs a floor: a point of it with nothing scanned below it (most
rays of a 20 deg cone around gravity escape; a wall over a part of the room whose floor was never
scanned) is unobserved too; a hole in the floor lets only a few rays through.

Per surface the rule is evaluated on a coarse grid in the surface's plane frame (NODE_SPACING apart,
DEPTH_LAYERS layers across each volume's depth), only where live cells' volumes reach; each cell's
unobserved share is the share of the grid nodes inside its volume that are not enclosed (a box sum).
"""

from __future__ import annotations

import numpy as np

from perch_common.raycast import RayScene, sphere_directions
from perch_common.viewpoints import seen_free
from perch_filtering.raster import SurfaceRaster

ESCAPE_DIRECTIONS = 32  # rays per grid node (Fibonacci sphere, fixed)
NODE_SPACING = 0.15     # m between grid nodes along the plane
DEPTH_LAYERS = 4        # node layers across a volume's depth (3 put a corridor's far half, over a floor hole, at 1 in 3)


DOWN_CONE_DEG = 20.0  # half angle of the cone of rays that looks for a floor below a fall volume's point


def down_cone(down: np.ndarray, half_angle_deg: float = DOWN_CONE_DEG, ring: int = 8) -> np.ndarray:
    """(ring + 1, 3) unit directions: `down` and a ring of `ring` around it at the half angle."""
    down = np.asarray(down, np.float64) / np.linalg.norm(down)
    side = np.cross(down, [1.0, 0, 0] if abs(down[0]) < 0.9 else [0, 1.0, 0])
    side /= np.linalg.norm(side)
    other = np.cross(down, side)
    t = np.radians(half_angle_deg)
    phi = np.arange(ring) * 2 * np.pi / ring
    around = np.cos(t) * down + np.sin(t) * (np.cos(phi)[:, None] * side + np.sin(phi)[:, None] * other)
    return np.vstack([down, around])


def escape_shares(scene: RayScene, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Per point, the share of rays in `directions` that leave the model without a hit."""
    if not len(points):
        return np.zeros(0)
    origins = np.repeat(points, len(directions), axis=0)
    hit = scene.any_hit(origins, np.tile(directions, (len(points), 1)))
    return (~hit).reshape(len(points), len(directions)).mean(axis=1)


def escapes(scene: RayScene, points: np.ndarray, directions: np.ndarray, share: float) -> np.ndarray:
    """escape_shares(scene, points, directions) > share, casting half the rays first: a point whose first
    half already settles the comparison whatever the other half does (inside a scanned room: every ray of
    the first half hits) gets no more rays."""
    n = len(directions)
    first, second = directions[0::2], directions[1::2]
    count = np.rint(escape_shares(scene, points, first) * len(first))  # escapes among the first half
    lowest, highest = count / n, (count + len(second)) / n
    out = lowest > share
    open_ = np.flatnonzero(~out & (highest > share))
    if len(open_):
        count = count[open_] + np.rint(escape_shares(scene, points[open_], second) * len(second))
        out[open_] = count / n > share
    return out


def unobserved_share(scene: RayScene, raster: SurfaceRaster, alive: np.ndarray, u_range: tuple[float, float],
                     v_range: tuple[float, float], depth_range: tuple[float, float],
                     enclosed_escape_share: float, down: np.ndarray | None = None,
                     viewpoints: np.ndarray | None = None) -> np.ndarray:
    """Per cell of `alive`, the share of its volume (plane offsets u_range x v_range around the cell,
    depth_range along the normal) the scan does not enclose (with `viewpoints`: no camera saw free);
    0 elsewhere. With `down` (a fall volume: the direction of gravity), a point with nothing scanned
    below it (down_cone) is unobserved too: a drone falling there would fall into space nobody saw."""
    return unobserved_shares(scene, raster, alive, u_range, v_range, depth_range, enclosed_escape_share, (down,),
                             viewpoints)[0]


def unobserved_shares(scene: RayScene, raster: SurfaceRaster, alive: np.ndarray, u_range: tuple[float, float],
                      v_range: tuple[float, float], depth_range: tuple[float, float],
                      enclosed_escape_share: float, downs: tuple[np.ndarray | None, ...],
                      viewpoints: np.ndarray | None = None) -> list[np.ndarray]:
    """unobserved_share of one volume for each `down` in `downs` (None: an approach; gravity: a fall),
    its nodes and their enclosure rays cast once: a ceiling's approach prism and fall column are one
    box with the default settings, and the fall asks only the floor test more."""
    if not alive.any():
        return [np.zeros(raster.shape, np.float32) for _ in downs]
    step = max(1, int(round(NODE_SPACING / raster.cell)))
    spacing = step * raster.cell
    # Node offsets (in nodes) inside each volume (a node beyond it, e.g. behind the next wall of a corner,
    # would count space outside the room), and the node grid reaching every live cell's volume.
    lo_u, hi_u = int(np.ceil(u_range[0] / spacing - 1e-9)), int(np.floor(u_range[1] / spacing + 1e-9))
    lo_v, hi_v = int(np.ceil(v_range[0] / spacing - 1e-9)), int(np.floor(v_range[1] / spacing + 1e-9))
    rows, cols = np.nonzero(alive)
    node_r, node_c = np.round(rows / step).astype(np.int64), np.round(cols / step).astype(np.int64)
    r0, c0 = node_r.min() + lo_v, node_c.min() + lo_u
    shape = (node_r.max() + hi_v - r0 + 1, node_c.max() + hi_u - c0 + 1)
    live = np.zeros(shape, bool)
    live[node_r - r0, node_c - c0] = True
    needed = np.zeros(shape, bool)  # every node some live node's volume reaches
    for dv in range(lo_v, hi_v + 1):
        for du in range(lo_u, hi_u + 1):
            needed[dv - lo_v:shape[0] - hi_v + dv, du - lo_u:shape[1] - hi_u + du] |= \
                live[-lo_v:shape[0] - hi_v, -lo_u:shape[1] - hi_u]
    nr, nc = np.nonzero(needed)
    uv = np.column_stack([raster.u0 + (nc + c0) * spacing, raster.v0 + (nr + r0) * spacing])
    depths = depth_range[0] + (np.arange(DEPTH_LAYERS) + 0.5) / DEPTH_LAYERS * (depth_range[1] - depth_range[0])
    points = np.concatenate([raster.frame.to_world(uv, np.full(len(uv), d)) for d in depths])
    if viewpoints is not None and len(viewpoints):
        enclosed_out = ~seen_free(scene, viewpoints, points)
    else:
        enclosed_out = escapes(scene, points, sphere_directions(ESCAPE_DIRECTIONS), enclosed_escape_share)
    rr, cc = node_r - r0, node_c - c0
    a, b = rr + lo_v, rr + hi_v + 1
    c, d = cc + lo_u, cc + hi_u + 1
    maps = []
    for down in downs:
        escaped = enclosed_out
        if down is not None:  # nothing scanned below: most of a narrow downward cone escapes (a hole lets a few out)
            escaped = enclosed_out.copy()
            rest = np.flatnonzero(~escaped)  # a point already unobserved needs no floor test
            escaped[rest] = escapes(scene, points[rest], down_cone(down), 0.5)
        unknown = np.zeros(shape, np.float64)
        unknown[nr, nc] = escaped.reshape(DEPTH_LAYERS, -1).mean(axis=0)  # the nodes are distinct
        # Box mean over each live node's volume (integral image; the grid covers every live volume).
        total = np.pad(unknown, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
        out = np.zeros(raster.shape, np.float32)
        out[rows, cols] = (total[b, d] - total[a, d] - total[b, c] + total[a, c]) / ((hi_v - lo_v + 1) * (hi_u - lo_u + 1))
        maps.append(out)
    return maps
