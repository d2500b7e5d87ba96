"""`perch bench reconstruct --bag BAG | --frames DIR --json`: speed, memory and quality figures."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.mesh import Mesh
from perch_reconstruction.bag_write import BagTopics


def register(sub) -> None:
    """Add `perch bench reconstruct`: fps with poses and odometry, ATE, Chamfer, cleaning, memory."""
    from perch_common.cli_types import non_negative_int, positive_float, positive_int

    parser = sub.add_parser("reconstruct", help="reconstruction: fps with poses and with odometry, ATE, "
                                                "Chamfer, cleaning time, memory")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--bag", help="ROS 2 MCAP bag with recorded poses")
    source.add_argument("--frames", help="TUM/7-Scenes-style frame folder with poses (converted to a bag first)")
    parser.add_argument("--limit", type=non_negative_int, default=0, help="--frames: at most this many frames (0: all)")
    parser.add_argument("--voxel-size", type=positive_float, help="TSDF voxel size (m, > 0; default: the config's)")
    parser.add_argument("--render", default="out/bench/reconstruct.png",
                        help="where to write a rendering of the pose-given mesh ('' = none)")
    parser.add_argument("--clean-faces", type=positive_int, default=1_000_000,
                        help="size of the mesh for the cleaning benchmark (faces, >= 1)")
    parser.add_argument("--json", action="store_true", help="print JSON (always on; kept for symmetry)")
    parser.set_defaults(func=run)


def subdivide(mesh: Mesh) -> Mesh:
    """Midpoint subdivision: every face into four (colours averaged on new vertices)."""
    f = mesh.faces
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges.sort(axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    mid = mesh.num_vertices + inverse.reshape(3, -1).T  # (F,3): midpoints of edges 01, 12, 20
    vertices = np.concatenate([mesh.vertices, mesh.vertices[unique].mean(axis=1)])
    colors = None
    if mesh.vertex_colors is not None:
        colors = np.concatenate([mesh.vertex_colors,
                                 mesh.vertex_colors[unique].astype(np.float64).mean(axis=1).astype(np.uint8)])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    faces = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                            np.stack([ab, bc, ca], 1)])
    return Mesh(vertices, faces, colors, frame_id=mesh.frame_id)


def run(args) -> int:
    """Run the reconstruction benchmark; prints JSON."""
    from perch_reconstruction.cleaning import clean_mesh_with_report
    from perch_reconstruction.cli import load_config
    from perch_reconstruction.core import reconstruct_bag
    from perch_reconstruction.metrics import ate_rmse, chamfer_distance, refine_alignment

    config = load_config()
    if args.voxel_size:
        config.voxel_size = args.voxel_size
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag
        if args.frames:
            bag = str(Path(tmp) / "frames.mcap")
            _convert(args.frames, bag, args.limit)
        started = time.perf_counter()
        pose_mesh, pose_stats = reconstruct_bag(bag, config, use_poses=True)
        wall_poses = time.perf_counter() - started
        started = time.perf_counter()
        odo_mesh, odo_stats = reconstruct_bag(bag, config, use_poses=False)
        wall_odometry = time.perf_counter() - started
    frames = pose_stats.frames_integrated
    ate, alignment = ate_rmse(odo_stats.trajectory, odo_stats.recorded)
    chamfer_trajectory = chamfer_distance(odo_stats.raw_mesh.transformed(alignment), pose_stats.raw_mesh,
                                          seed=config.seed)
    surface_alignment = refine_alignment(odo_stats.raw_mesh, pose_stats.raw_mesh, alignment, seed=config.seed)
    chamfer = chamfer_distance(odo_stats.raw_mesh.transformed(surface_alignment), pose_stats.raw_mesh,
                               seed=config.seed)
    big = pose_stats.raw_mesh
    while big.num_faces < args.clean_faces:
        big = subdivide(big)
    if big.num_faces > args.clean_faces:  # a contiguous slab of the subdivided room, exactly the size asked
        order = np.argsort(big.face_centroids()[:, 0], kind="stable")
        big = big.submesh(np.sort(order[:args.clean_faces]))
    _, big_report = clean_mesh_with_report(big, None, config, pose_stats.clean.rotation.T @ [0, 0, -1.0])
    result = {
        "source": args.bag or args.frames, "frames": frames, "image_size": list(pose_stats.image_size),
        "voxel_size_m": config.voxel_size,
        "fps_integrate": frames / max(pose_stats.seconds_integrate, 1e-9),
        "fps_integrate_wall": frames / wall_poses,
        "fps_odometry": odo_stats.frames_integrated / max(odo_stats.seconds_track + odo_stats.seconds_integrate, 1e-9),
        "fps_odometry_wall": odo_stats.frames_integrated / wall_odometry,
        "frames_lost_odometry": odo_stats.frames_lost,
        "ate_rmse_m": ate, "chamfer_m": chamfer, "chamfer_trajectory_aligned_m": chamfer_trajectory,
        "seconds_clean": pose_stats.seconds_clean, "faces_raw": pose_stats.faces_raw, "faces": pose_mesh.num_faces,
        "up_source": pose_stats.clean.up_source,
        "clean_big_faces_in": big_report.faces_in, "clean_big_faces_out": big_report.faces_out,
        "seconds_clean_big": big_report.seconds,
        "blocks": pose_stats.blocks, "peak_rss_mb": peak_rss_mb(),
        "cpu_count": os.cpu_count(), "load_average_1min": os.getloadavg()[0],  # shared machines skew fps
    }
    if args.render:
        from perch_reconstruction.render import save_rendering

        result["rendering"] = str(save_rendering(args.render, pose_mesh))
    return emit(result)


def _convert(frames_dir: str, bag: str, limit: int) -> None:
    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.frames import iter_folder_frames, open_frame_folder

    folder = open_frame_folder(frames_dir, limit=limit or None)
    write_bag(bag, iter_folder_frames(folder), folder.intrinsics, gravity=folder.gravity, topics=BagTopics())
