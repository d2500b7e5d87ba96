"""Synthetic RGB-D frames ray-cast from a mesh (generated scenes), so tests exercise the full path."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_reconstruction.frames import Intrinsics, RGBDFrame

DEFAULT_INTRINSICS = Intrinsics(320, 240, 190.0, 190.0, 159.5, 119.5)  # ~80 deg wide: rooms stay well constrained


def look_pose(position: np.ndarray, yaw: float, pitch: float) -> np.ndarray:
    """World-from-camera (optical frame: x right, y down, z forward) for a z-up world."""
    forward = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, forward])
    pose[:3, 3] = position
    return pose


def pan_trajectory(center: np.ndarray, count: int, *, height: float = 1.5, turn: float = 2 * np.pi,
                   pitch_deg: float = -20.0, sway: float = 0.3, seed: int = 0) -> list[np.ndarray]:
    """A camera turning on the spot while swaying on a small circle (a drone surveying a room)."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 2 * np.pi)
    poses = []
    for i in range(count):
        t = i / max(count - 1, 1)
        yaw = start + turn * t
        offset = sway * np.array([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t), 0.0])
        position = np.array([center[0], center[1], height]) + offset
        pitch = np.radians(pitch_deg) + 0.1 * np.sin(4 * np.pi * t)
        poses.append(look_pose(position, yaw, pitch))
    return poses


def render_frame(scene: RayScene, mesh: Mesh, intrinsics: Intrinsics, pose: np.ndarray, stamp_ns: int = 0,
                 depth_noise: float = 0.0, rng: np.random.Generator | None = None,
                 face_colors: np.ndarray | None = None) -> RGBDFrame:
    """Depth (z along the optical axis, metres) and colour seen from `pose`; misses are 0."""
    u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
    rays_cam = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                         np.ones_like(u, dtype=np.float64)], axis=-1).reshape(-1, 3)
    dirs = rays_cam @ pose[:3, :3].T  # unit z in camera: t_hit is the depth itself
    hits = scene.cast(np.broadcast_to(pose[:3, 3], dirs.shape), dirs)
    depth = np.where(hits.hit, hits.distance, 0.0)
    if depth_noise > 0 and rng is not None:
        depth = np.where(depth > 0, depth + rng.normal(0, depth_noise, depth.shape) * depth ** 2, 0.0)
    colors = face_colors if face_colors is not None else _face_colors(mesh)
    color = np.zeros((len(dirs), 3), np.uint8)
    color[hits.hit] = colors[hits.face[hits.hit]]
    shape = (intrinsics.height, intrinsics.width)
    return RGBDFrame(color.reshape(*shape, 3), depth.reshape(shape).astype(np.float32), stamp_ns, pose.copy())


def _face_colors(mesh: Mesh) -> np.ndarray:
    if mesh.vertex_colors is None:
        return np.full((mesh.num_faces, 3), 180, np.uint8)
    return np.round(mesh.face_colors() * 255).astype(np.uint8)


def render_sequence(mesh: Mesh, poses: list[np.ndarray], intrinsics: Intrinsics = DEFAULT_INTRINSICS,
                    fps: float = 30.0, depth_noise: float = 0.0, seed: int = 0) -> list[RGBDFrame]:
    """Simulated RGB-D frames (noisy depth, seeded) of the mesh seen from the poses."""
    scene = RayScene(mesh)
    colors = _face_colors(mesh)
    rng = np.random.default_rng(seed)
    period = int(round(1e9 / fps))
    return [render_frame(scene, mesh, intrinsics, pose, (i + 1) * period, depth_noise, rng, colors)
            for i, pose in enumerate(poses)]


def synthetic_room_frames(seed: int = 0, count: int = 40, intrinsics: Intrinsics = DEFAULT_INTRINSICS,
                          kind: str = "room", turn: float = np.pi):
    """(scene, frames) for a generated room seen by a camera turning `turn` radians near its centre."""
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(seed, kind, resolution=0.1)
    center = scene.target.center
    floor = float(scene.mesh.bounds()[0, 2])
    poses = pan_trajectory(center, count, height=floor + 1.4, turn=turn, seed=seed)
    return scene, render_sequence(scene.mesh, poses, intrinsics, seed=seed)


def write_frame_folder(folder, frames: list[RGBDFrame], intrinsics: Intrinsics,
                       gravity: np.ndarray | None = None) -> None:
    """Write frames in the 7-Scenes layout (colour PNG, 16-bit depth PNG in mm, pose, intrinsics)."""
    from pathlib import Path

    import cv2

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    np.savetxt(folder / "camera-intrinsics.txt", intrinsics.matrix())
    if gravity is not None:
        np.savetxt(folder / "gravity-direction.txt", np.asarray(gravity, np.float64).reshape(3))
    for i, frame in enumerate(frames):
        stem = folder / f"frame-{i:06d}"
        cv2.imwrite(f"{stem}.color.png", frame.color[:, :, ::-1])
        cv2.imwrite(f"{stem}.depth.png", np.clip(np.round(frame.depth * 1000), 0, 65534).astype(np.uint16))
        if frame.pose is not None:
            np.savetxt(f"{stem}.pose.txt", frame.pose)
