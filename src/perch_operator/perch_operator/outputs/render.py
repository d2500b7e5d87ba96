"""Pictures of a mission: the overview from above (ray cast, ceiling cut away) with regions, target,
cameras and rejected perches drawn on it; each camera's simulated view (perch_placement.render).
"""

from __future__ import annotations

import importlib.util

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_operator.outputs.mission_data import MissionData

# BGR colours (OpenCV)
REGION = (80, 200, 80)
TARGET = (0, 140, 255)
CAMERA = (220, 60, 20)
REJECTED = (40, 40, 230)


class TopView:
    """Orthographic view from above: world xy <-> pixel, north (+y) up."""

    def __init__(self, bounds: np.ndarray, size: int = 900, margin: float = 0.3):
        lo, hi = bounds[0, :2] - margin, bounds[1, :2] + margin
        self.res = float(max(hi - lo) / size)
        self.lo, self.hi = lo, hi
        self.width = int(np.ceil((hi[0] - lo[0]) / self.res))
        self.height = int(np.ceil((hi[1] - lo[1]) / self.res))

    def pixels(self, xy: np.ndarray) -> np.ndarray:
        """(N,2) pixel coordinates of plan positions."""
        xy = np.asarray(xy, np.float64)
        xy = xy.reshape(-1, xy.shape[-1])[:, :2]
        return np.column_stack([(xy[:, 0] - self.lo[0]) / self.res, (self.hi[1] - xy[:, 1]) / self.res])

    def cell_centres(self) -> np.ndarray:
        """(W*H,2) plan positions of the pixel centres."""
        u, v = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        return np.column_stack([self.lo[0] + u.ravel() * self.res, self.hi[1] - v.ravel() * self.res])


LIGHT = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])   # the top view's light direction


def shaded_top_view(mesh: Mesh, view: TopView) -> np.ndarray:
    """(H,W,3) uint8 BGR: the mesh seen from above with downward-facing faces (ceilings) culled."""
    normals = mesh.face_normals()
    visible = np.flatnonzero(normals[:, 2] > -0.2)
    image = np.full((view.height * view.width, 3), 255, np.uint8)
    if len(visible) == 0:
        return image.reshape(view.height, view.width, 3)
    # The scene needs only the visible faces' indices, not a submesh (unused vertices cost nothing).
    upward = Mesh(mesh.vertices, mesh.faces[visible], frame_id=mesh.frame_id)
    xy = view.cell_centres()
    origins = np.empty((len(xy), 3), np.float32)
    origins[:, :2] = xy
    origins[:, 2] = mesh.bounds()[1, 2] + 1.0
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0], np.float32), origins.shape)
    hits = RayScene(upward).cast(origins, down)
    rows = np.flatnonzero(hits.hit)
    normal = hits.normal[rows]
    # n . light written out (a matrix-vector product goes to threaded BLAS); float32 from here, as
    # the result is 8-bit. The level is at most 255 (+ rounding): below 256 with any albedo <= 1.
    light = np.abs(normal[:, 0] * LIGHT[0] + normal[:, 1] * LIGHT[1] + normal[:, 2] * LIGHT[2]).astype(np.float32)
    level = (0.45 * 255 + 0.55 * 255 * light)[:, None]   # 255 x the light on each hit pixel
    table = mesh.face_color_table()
    albedo = np.float32(0.75) if table is None else table[visible[hits.face[rows]], ::-1]   # BGR
    image[rows] = albedo * level   # truncated to uint8, as before
    return image.reshape(view.height, view.width, 3)


def overview(data: MissionData, size: int = 900) -> np.ndarray:
    """The annotated overview image (BGR)."""
    import cv2

    mesh = data.mesh if data.mesh is not None else data.cropped
    view = TopView(mesh.bounds(), size)
    image = shaded_top_view(mesh, view)
    layer = image.copy()
    for region in data.regions:
        tris = view.pixels(region.mesh.triangles().reshape(-1, 3)).reshape(-1, 3, 2)
        cv2.fillPoly(layer, list(np.round(tris).astype(np.int32)), REGION, lineType=cv2.LINE_AA)
    image = cv2.addWeighted(layer, 0.45, image, 0.55, 0)
    edges = np.zeros((0, 2, 3)) if data.target is None else data.target.edges()
    if len(edges):
        # Every edge a two-point polyline, in one call: what cv2.line draws for each, in the same order.
        ends = np.round(view.pixels(edges.reshape(-1, 3))).astype(np.int32).reshape(-1, 2, 1, 2)
        cv2.polylines(image, list(ends), False, TARGET, 2, cv2.LINE_AA)
    for placement, _ in data.rejected:
        centre = _pt(view.pixels(np.asarray(placement.drone_pose)[:3, 3][None])[0])
        cv2.drawMarker(image, centre, REJECTED, cv2.MARKER_TILTED_CROSS, 14, 2)
        cv2.circle(image, centre, max(2, int(0.3 / view.res)), REJECTED, 1, cv2.LINE_AA)
    for p in data.placements:
        pose = np.asarray(p.camera_pose)
        centre = view.pixels(pose[:3, 3][None])[0]
        heading = np.array([pose[0, 2], -pose[1, 2]])  # viewing direction in pixels (y flipped)
        if np.linalg.norm(heading) > 0.05:  # a camera looking straight down has no heading to draw
            ahead = centre + 35 * heading / np.linalg.norm(heading)
            cv2.arrowedLine(image, _pt(centre), _pt(ahead), CAMERA, 2, cv2.LINE_AA, tipLength=0.3)
        cv2.circle(image, _pt(centre), 7, CAMERA, -1, cv2.LINE_AA)
        cv2.putText(image, str(p.drone_index), _pt(centre + [9, -9]), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2,
                    cv2.LINE_AA)
    _legend(image)
    return image


def _legend(image: np.ndarray) -> None:
    import cv2

    items = [("perch regions", REGION), ("target volume", TARGET), ("camera (drone index)", CAMERA),
             ("rejected perch", REJECTED)]
    for i, (text, colour) in enumerate(items):
        y = 20 + 20 * i
        cv2.rectangle(image, (10, y - 10), (22, y + 2), colour, -1)
        cv2.putText(image, text, (28, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (30, 30, 30), 1, cv2.LINE_AA)


def _pt(p) -> tuple[int, int]:
    return int(round(float(p[0]))), int(round(float(p[1])))


def camera_views(data: MissionData) -> list[np.ndarray | None]:
    """Each accepted camera's simulated RGB view (BGR uint8), by perch_placement's renderer.

    Empty when perch_placement (with its renderer) is not installed.
    """
    if importlib.util.find_spec("perch_placement") is None or \
            importlib.util.find_spec("perch_placement.render") is None or data.mesh is None:
        return []
    from perch_operator.outputs.mission_data import placement_config
    from perch_placement.core import scene_for
    from perch_placement.render import render_view

    camera = placement_config().camera
    scene = scene_for(data.mesh) if data.placements else None  # one BVH for every view
    out: list[np.ndarray | None] = []
    for placement in data.placements:
        rgb, _depth = render_view(data.mesh, placement, camera, data.target, scene=scene)
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8:
            rgb = (np.clip(rgb, 0, 1) * 255).astype(np.uint8)
        out.append(np.ascontiguousarray(rgb[:, :, ::-1]))
    return out
