"""What a placed camera sees: colour and depth by ray casting the mesh, the target's edges drawn,
and per-camera scores of the target points (for the operator and the report)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.target import TargetVolume
from perch_common.types import CameraPlacement
from perch_placement.camera import project, undistort
from perch_placement.config import CameraSpec
from perch_placement.fitness import Evaluator, placement_cameras, point_score

TARGET_COLOUR = (255, 80, 0)          # target edges in front of the scene
HIDDEN_TARGET_COLOUR = (140, 70, 160)  # target edges behind geometry


def pixel_rays(camera: CameraSpec, width: int, height: int, zoom: float = 1.0) -> np.ndarray:
    """(H,W,3) optical-frame directions (z = 1) through the centres of an image of width x height,
    the camera's sensor resampled to that size, distortion inverted."""
    sx, sy = camera.width / width, camera.height / height
    u = (np.arange(width) + 0.5) * sx
    v = (np.arange(height) + 0.5) * sy
    uu, vv = np.meshgrid(u, v)
    xd = (uu - camera.cx) / (camera.fx * zoom)
    yd = (vv - camera.cy) / (camera.fy * zoom)
    x, y = undistort(xd, yd, camera.distortion)
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def render_view(mesh: Mesh, placement: CameraPlacement, camera: CameraSpec, target: TargetVolume | None = None,
                scale: float = 0.5, scene: RayScene | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Colour (H,W,3) uint8 and depth (H,W) float32 (metres along the optical axis, 0 where nothing
    is hit) seen from the placement's camera pose, at `scale` times the sensor resolution."""
    from perch_placement.core import scene_for

    width, height = max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale)))
    scene = scene or scene_for(mesh)
    pose = np.asarray(placement.camera_pose, np.float64)
    rays = pixel_rays(camera, width, height, max(float(placement.zoom), 1.0))
    world_dirs = rotate_directions(rays.reshape(-1, 3), pose[:3, :3])
    # One origin for every ray, broadcast rather than repeated: the cast packs rays into float32 anyway.
    hits = scene.cast(np.broadcast_to(pose[:3, 3].astype(np.float32), world_dirs.shape), world_dirs)
    hit = hits.hit & np.isfinite(hits.distance)
    depth = np.where(hit, hits.distance, 0.0).astype(np.float32).reshape(height, width)  # z = 1 rays
    colour = _shade(mesh, hits, world_dirs, hit).reshape(height, width, 3)
    if target is not None:
        colour = draw_target(colour, depth, target, placement, camera, scale)
    return colour, depth


def rotate_directions(directions: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(N,3) float32 `directions @ rotation.T`, written out column by column: numpy sends an
    (N,3) @ (3,3) product to multi-threaded BLAS, which spins for ~80 ms a view when the other core
    is busy (1 ms otherwise); this costs a few ms either way."""
    d = np.asarray(directions, np.float64)
    r = np.asarray(rotation, np.float64)
    out = np.empty((len(d), 3), np.float32)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    for k in range(3):
        out[:, k] = x * r[k, 0] + y * r[k, 1] + z * r[k, 2]
    return out


def _shade(mesh: Mesh, hits, dirs: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Face colour (grey without colours) times a head-light Lambert term; black sky.

    Every ray is shaded and misses are zeroed after (cheaper than gathering the hit rows); float32
    once the Lambert term is known, as the result is 8-bit."""
    n, d = hits.normal, dirs
    lambert = np.abs(n[:, 0] * d[:, 0] + n[:, 1] * d[:, 1] + n[:, 2] * d[:, 2]) / np.sqrt(np.einsum("ij,ij->i", d, d))
    # 255 x the light on each pixel, 0 on misses; at most 255 (+ rounding), so below 256 with any albedo <= 1
    level = np.where(hit, 0.35 * 255 + 0.65 * 255 * lambert, 0.0).astype(np.float32)[:, None]
    table = mesh.face_color_table()   # per face, computed once per mesh for every view
    if table is None:
        return np.repeat((np.float32(0.75) * level).astype(np.uint8), 3, axis=1)
    return (table[np.where(hit, hits.face, 0)] * level).astype(np.uint8)   # truncated, as before


def draw_target(colour: np.ndarray, depth: np.ndarray, target: TargetVolume, placement: CameraPlacement,
                camera: CameraSpec, scale: float, samples_per_metre: float = 200.0) -> np.ndarray:
    """The target volume's edges (target_outline), sampled densely and projected (distortion
    included): bright where in front of the scene, dim where hidden."""
    import cv2

    out = np.ascontiguousarray(colour.copy())
    pose = np.asarray(placement.camera_pose, np.float64)
    edges = target_outline(target)
    counts = np.maximum(2, (np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1) * samples_per_metre).astype(int))
    edge = np.repeat(np.arange(len(edges)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)  # each sample's edge's first sample
    t = (np.arange(len(edge)) - first) / (counts[edge] - 1)  # 0..1 along its edge, as linspace
    pts = edges[edge, 0] + t[:, None] * (edges[edge, 1] - edges[edge, 0])
    local = (pts - pose[:3, 3]) @ pose[:3, :3]
    pix, ok = project(camera, local, max(float(placement.zoom), 1.0))
    pix = pix * scale
    h, w = depth.shape
    scene_depth = depth[np.clip(pix[:, 1].astype(int), 0, h - 1), np.clip(pix[:, 0].astype(int), 0, w - 1)]
    front = (scene_depth == 0) | (local[:, 2] <= scene_depth * 1.01 + 0.02)
    # Segments between consecutive samples of the same edge, both imaged.
    seg = np.flatnonzero((edge[:-1] == edge[1:]) & ok[:-1] & ok[1:])
    lines = np.round(np.stack([pix[seg], pix[seg + 1]], axis=1)).astype(np.int32).reshape(-1, 2, 1, 2)
    for visible, colour_, width in ((False, HIDDEN_TARGET_COLOUR, 1), (True, TARGET_COLOUR, 2)):
        chosen = lines[front[seg] == visible]
        if len(chosen):
            cv2.polylines(out, list(chosen), False, colour_, width, cv2.LINE_AA)
    return out


def target_outline(target: TargetVolume, tolerance: float = 0.05) -> np.ndarray:
    """(E,2,3) edges to draw: a box's 12 edges; a footprint's outline at the base and the top, with
    vertical edges only at the corners of the outline simplified to `tolerance` metres (a scanned
    footprint has hundreds of vertices)."""
    if target.is_box:
        return target.edges()
    import shapely

    ring = np.asarray(target.footprint)
    corners = np.asarray(shapely.Polygon(ring).simplify(tolerance).exterior.coords)[:-1]
    low, high = target.base, target.base + target.height
    edges = []
    nxt = np.roll(ring, -1, axis=0)
    for z in (low, high):
        edges.append(np.stack([np.column_stack([ring, np.full(len(ring), z)]),
                               np.column_stack([nxt, np.full(len(nxt), z)])], axis=1))
    edges.append(np.stack([np.column_stack([corners, np.full(len(corners), low)]),
                           np.column_stack([corners, np.full(len(corners), high)])], axis=1))
    return np.concatenate(edges)


@dataclass
class PointScores:
    """Each target point's score per camera and fused, for colouring points."""

    points: np.ndarray      # (N,3) target points
    seen: np.ndarray        # (K,N) camera k sees point n
    per_camera: np.ndarray  # (K,N) score 1 - ||C||/||C_max|| of camera k alone (0 unseen)
    fused: np.ndarray       # (N,) score of all cameras together


def point_scores(mesh: Mesh, placements: list[CameraPlacement], camera: CameraSpec, points: np.ndarray,
                 epsilon: float = 1e-3, scene: RayScene | None = None) -> PointScores:
    """Each target point's score per camera and fused, for colouring points in a visualisation."""
    from perch_placement.core import scene_for

    ev = Evaluator(scene or scene_for(mesh), points, camera, epsilon)
    if not placements:
        empty = np.zeros((0, ev.count))
        return PointScores(ev.points, empty.astype(bool), empty, np.zeros(ev.count))
    seen, info = ev.views(*placement_cameras(placements))
    per_camera = point_score(info, seen)[0]
    fused = point_score(info.sum(axis=0), seen.any(axis=0))[0]
    return PointScores(ev.points, seen, per_camera, fused)
