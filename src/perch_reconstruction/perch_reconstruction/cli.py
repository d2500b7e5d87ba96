"""`perch bag ...`, `perch clean`, `perch reconstruct` (registered through perch.commands)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from perch_common.cli_types import non_negative_float
from perch_common.errors import PerchError
from perch_common.mesh import add_units_arguments
from perch_common.outputs import atomic_path, refuse_overwriting_inputs
from perch_common.up_axis import add_up_argument, up_for_file
from perch_reconstruction.bag_write import BagTopics
from perch_reconstruction.config import ReconstructionConfig


def load_config(path: str | None = None) -> ReconstructionConfig:
    """The perch_reconstruction section of config/perch.yaml (or `path`), defaults when absent."""
    from perch_common.config import ConfigError, default_config_path, from_parameters, node_parameters

    try:
        params = node_parameters("perch_reconstruction", path or default_config_path())
    except ConfigError:
        if path:
            raise
        params = {}
    return from_parameters(ReconstructionConfig, params).validate()


def _config_with(path: str | None, **overrides) -> ReconstructionConfig:
    """load_config(path) with the command-line values that were given (None = keep the file's)."""
    config = load_config(path)
    for name, value in overrides.items():
        if value is not None:
            setattr(config, name, value)
    return config.validate()


def _topic_args(parser) -> None:
    d = BagTopics()
    parser.add_argument("--color-topic", default=d.color)
    parser.add_argument("--depth-topic", default=d.depth)
    parser.add_argument("--info-topic", default=d.camera_info)
    parser.add_argument("--pose-topic", default=d.pose)


def _topics(args) -> BagTopics:
    return BagTopics(args.color_topic, args.depth_topic, args.info_topic, args.pose_topic)


# --- perch bag -----------------------------------------------------------------------------------

def register_bag(sub) -> None:
    """Add `perch bag`: convert frame folders to bags, inspect them, play them on the graph."""
    parser = sub.add_parser("bag", help="RGB-D bags: convert frames, inspect, play on the graph")
    bag = parser.add_subparsers(dest="bag_command", metavar="ACTION")
    conv = bag.add_parser("from-frames", help="TUM/7-Scenes-style folder -> ROS 2 MCAP bag")
    conv.add_argument("frames", help="folder with frame-*.color.jpg, frame-*.depth.png (mm), poses, intrinsics")
    conv.add_argument("-o", "--output", required=True, help="bag file to write (.mcap)")
    conv.add_argument("--fps", type=float, default=30.0,
                      help="frame rate of the time stamps when the folder has no timestamps.txt")
    conv.add_argument("--start", default="now", metavar="TIME",
                      help="time of the first frame when the folder has no timestamps.txt: 'now' (default), "
                           "Unix seconds or ISO 8601 (2024-05-01T10:00:00Z)")
    conv.add_argument("--limit", type=int, default=0, help="convert at most this many frames")
    conv.add_argument("--step", type=int, default=1, help="take every N-th frame")
    conv.add_argument("--compressed", action="store_true", help="CompressedImage (JPEG colour, PNG depth)")
    conv.add_argument("--pose-type", choices=("pose", "odometry", "tf"), default="pose",
                      help="poses as geometry_msgs/PoseStamped, nav_msgs/Odometry or only as /tf (they go on /tf "
                           "in every case)")
    conv.add_argument("--no-poses", action="store_true", help="leave the poses out")
    _topic_args(conv)
    conv.set_defaults(func=_from_frames)
    info = bag.add_parser("info", help="topics, types, counts and duration of a bag")
    info.add_argument("bag")
    info.add_argument("--json", action="store_true")
    info.set_defaults(func=_info)
    play = bag.add_parser("play", help="publish a bag's messages in time order")
    play.add_argument("bag")
    play.add_argument("--rate", type=non_negative_float, default=1.0, help="speed factor (0: as fast as possible)")
    play.add_argument("--topics", nargs="+", help="only these topics")
    play.add_argument("--wait-subscribers", type=non_negative_float, default=0.0,
                      help="wait up to this many seconds for subscribers before starting")
    play.set_defaults(func=_play)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)


def _from_frames(args) -> int:
    import sys
    import time

    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.frames import folder_stamps, iter_folder_frames, open_frame_folder, parse_start

    if args.fps <= 0:
        raise ValueError(f"--fps must be > 0, got {args.fps}")
    refuse_overwriting_inputs([args.output], [args.frames])
    folder = open_frame_folder(args.frames, limit=args.limit or None, step=args.step)
    stamps, source = folder_stamps(folder, args.fps, parse_start(args.start))
    print(f"perch bag from-frames: {len(folder)} frames, stamps from {source}", file=sys.stderr, flush=True)
    if folder.frames_without_pose_file and not args.no_poses:
        print(f"perch bag from-frames: warning: {folder.frames_without_pose_file} of {len(folder)} frames have no "
              ".pose.txt; they are written without a pose (a reconstruction from the recorded poses skips them, as "
              "frames whose tracking was lost; --no-poses writes none and lets odometry track every frame)",
              file=sys.stderr, flush=True)
    shown = [time.monotonic()]

    def frames():
        for i, frame in enumerate(iter_folder_frames(folder, stamps=stamps)):
            if args.no_poses:
                frame.pose = None
            if time.monotonic() - shown[0] >= 1.0 or i + 1 == len(folder):
                shown[0] = time.monotonic()
                print(f"perch bag from-frames: {i + 1}/{len(folder)} frames ({100 * (i + 1) // len(folder)} %)",
                      file=sys.stderr, flush=True)
            yield frame

    result = write_bag(args.output, frames(), folder.intrinsics, gravity=folder.gravity, topics=_topics(args),
                       compressed=args.compressed, pose_type=args.pose_type)
    result["stamps_from"] = source
    result["frames_without_pose_file"] = folder.frames_without_pose_file
    print(json.dumps(result, indent=2))
    return 0


def _info(args) -> int:
    from perch_reconstruction.bag_read import bag_info

    info = bag_info(args.bag)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"{info['path']}: {info['messages']} messages, {info['duration_s']:.2f} s")
    width = max((len(t) for t in info["topics"]), default=0)
    for topic, t in info["topics"].items():
        print(f"  {topic:<{width}}  {t['count']:>6}  {t['type']} ({t['encoding']})")
    if info["gravity"] is not None:
        print(f"  gravity (world frame): {info['gravity']}")
    for problem in info["problems"]:
        print(f"  DAMAGED: {problem}")
    if info["recovered"]:
        print("  the counts above are what could be read; `perch reconstruct` and `perch plan --bag` use them")
    return 0


def _play(args) -> int:
    from perch_reconstruction.player import play_bag

    counts = play_bag(args.bag, args.rate, args.topics, args.wait_subscribers)
    print(json.dumps({"published": counts}))
    return 0


# --- perch clean ---------------------------------------------------------------------------------

def register_clean(sub) -> None:
    """Add `perch clean`: merge, drop small pieces, decimate and gravity-align a mesh."""
    parser = sub.add_parser("clean", help="clean a mesh: merge, drop small pieces, decimate, gravity-align")
    parser.add_argument("mesh")
    parser.add_argument("-o", "--output", required=True)
    add_up_argument(parser)
    parser.add_argument("--gravity", nargs=3, type=float, metavar=("X", "Y", "Z"),
                        help="gravity direction in the mesh frame (overrides --up)")
    parser.add_argument("--target-faces", type=int, help="decimation target (0: none)")
    parser.add_argument("--min-piece", type=float, help="remove pieces smaller than this diameter (m)")
    parser.add_argument("--no-align", action="store_true", help="keep the orientation")
    add_units_arguments(parser)
    parser.add_argument("--config", help="parameter file (default config/perch.yaml)")
    parser.set_defaults(func=_clean)


def _clean(args) -> int:
    from perch_common.mesh import load_mesh, mesh_output, save_mesh
    from perch_reconstruction.cleaning import clean_mesh_with_report

    mesh_output(args.output)
    refuse_overwriting_inputs([args.output], [args.mesh, args.config])
    if args.gravity and not (np.isfinite(args.gravity).all() and np.linalg.norm(args.gravity) > 0):
        raise PerchError(f"--gravity {' '.join(f'{g:g}' for g in args.gravity)}: give a finite, non-zero direction "
                         "(or leave it out: --up chooses)")
    config = _config_with(args.config, target_faces=args.target_faces, min_piece_diameter=args.min_piece,
                          gravity_align=False if args.no_align else None)
    mesh = load_mesh(args.mesh, scale=args.scale, shift=args.shift)
    up = {}
    if args.gravity:
        gravity = np.array(args.gravity)
    else:  # the up axis as perch plan would take it (a contradicted --up stops here)
        choice = up_for_file(args.up, mesh, args.mesh)
        gravity = -choice.up
        # The core is given this up as gravity; the JSON says where it came from and how sure it is (the
        # core's "gravity, 1.00" contradicted an unsure estimate's warning).
        up = {"up": choice.up.round(6).tolist(), "up_from": choice.source, "up_source": choice.source,
              "up_confidence": round(choice.estimate.confidence, 3),
              "up_estimate_confidence": round(choice.estimate.confidence, 3), "up_evidence": choice.estimate.evidence()}
    mesh, report = clean_mesh_with_report(mesh, gravity, config)
    with atomic_path(args.output) as partial:
        save_mesh(partial, mesh)
    print(json.dumps({"output": args.output, "faces_in": report.faces_in, "faces_out": report.faces_out,
                      "small_piece_faces_removed": report.pieces_removed_faces, "up_source": report.up_source,
                      "up_confidence": round(report.up_confidence, 3), **up,
                      "rotation": np.round(report.rotation, 9).tolist(),  # output = rotation @ input
                      "seconds": round(report.seconds, 3),
                      "warnings": report.warnings + (choice.warnings if not args.gravity else [])}, indent=2))
    return 0


# --- perch reconstruct ---------------------------------------------------------------------------

def register_reconstruct(sub) -> None:
    """Add `perch reconstruct`: an RGB-D bag or frame folder to a clean mesh."""
    parser = sub.add_parser("reconstruct", help="RGB-D bag (or frame folder) -> clean gravity-aligned mesh")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--bag", help="ROS 2 MCAP bag")
    source.add_argument("--frames", help="TUM/7-Scenes-style frame folder")
    parser.add_argument("-o", "--output", required=True, help="mesh file (.ply, .obj, ...)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--use-poses", dest="use_poses", action="store_true", default=True,
                      help="integrate the recorded poses (default)")
    mode.add_argument("--odometry", dest="use_poses", action="store_false", help="track the camera (RGB-D odometry)")
    parser.add_argument("--voxel-size", type=float, help="TSDF voxel size (m)")
    parser.add_argument("--target-faces", type=int)
    parser.add_argument("--raw", help="also write the uncleaned TSDF surface here")
    parser.add_argument("--limit", type=int, default=0, help="--frames: use at most this many frames")
    parser.add_argument("--config", help="parameter file (default config/perch.yaml)")
    _topic_args(parser)
    parser.set_defaults(func=_reconstruct)


def _reconstruct(args) -> int:
    from perch_common.mesh import mesh_output, save_mesh
    from perch_common.viewpoints import write_viewpoints_beside
    from perch_reconstruction.bag_read import bag_info, frames_damage
    from perch_reconstruction.core import reconstruct_bag, reconstruct_frames

    mesh_output(args.output)
    mesh_output(args.raw, "--raw")
    refuse_overwriting_inputs([args.output, args.raw], [args.bag, args.frames, args.config])
    config = _config_with(args.config, voxel_size=args.voxel_size, target_faces=args.target_faces)

    def progress(s) -> None:
        print(f"  {s.frames_integrated}/{s.frames_received} frames integrated", flush=True)

    if args.bag:
        mesh, stats = reconstruct_bag(args.bag, config, args.use_poses, _topics(args), progress=progress)
    else:
        from perch_reconstruction.frames import iter_folder_frames, open_frame_folder

        folder = open_frame_folder(args.frames, limit=args.limit or None)
        if args.use_poses and not folder.has_poses:
            raise PerchError(f"{args.frames}: no frame-*.pose.txt files; use --odometry")
        mesh, stats = reconstruct_frames(iter_folder_frames(folder), folder.intrinsics, config, args.use_poses,
                                         folder.gravity, progress=progress)
    if args.raw:
        with atomic_path(args.raw) as partial:
            save_mesh(partial, stats.raw_mesh)
    with atomic_path(args.output) as partial:
        save_mesh(partial, mesh)
    if mesh.viewpoints is not None:   # mesh formats cannot hold them: beside the file, for planning from it
        write_viewpoints_beside(args.output, mesh.vertices, mesh.faces, mesh.viewpoints)
    damage = frames_damage(bag_info(args.bag), _topics(args)) if args.bag else ""   # the scan is cached
    print(json.dumps({"output": str(Path(args.output)), **stats.summary(), "faces": mesh.num_faces,
                      **({"damage": damage} if damage else {})}, indent=2))
    if damage:   # last, where it is seen: the frame counts above are of what could be read
        print(f"perch: warning: {damage}", file=sys.stderr, flush=True)
    return 0
