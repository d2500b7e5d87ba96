"""`perch place MESH --target FOOTPRINT --cameras 5 -o OUT`: placements as YAML, simulated views as PNG."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from perch_placement.cli_problem import add_problem_arguments, load_config, load_problem, up_of
from perch_placement.search import METHODS

MAX_VIEW_SCALE = 4.0   # views beyond 4x the sensor's size are images of hundreds of megapixels


def register(sub) -> None:
    """Add `perch place`: choose perches on a mesh, write placements.yaml and simulated views."""
    parser = sub.add_parser("place", help="choose camera perches on a mesh (placement stage)",
                            description="Place camera drones to observe a target volume; writes "
                                        "placements.yaml and one colour + depth view per camera.")
    add_problem_arguments(parser, mesh_positional=True)
    parser.add_argument("--cameras", type=int, default=None, help="cameras to place (default: config)")
    parser.add_argument("--method", choices=METHODS, default=None, help="search method (default: config)")
    parser.add_argument("--seed", type=int, default=None, help="search seed (default: config)")
    parser.add_argument("--view-scale", type=float, default=0.5,
                        help=f"rendered view size / sensor size (above 0, at most {MAX_VIEW_SCALE:g})")
    parser.add_argument("-o", "--output", required=True, help="output folder")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run `perch place`; exit code 1 when no camera could be placed."""
    from perch_common.outputs import check_writable_folder
    from perch_placement.core import optimise

    if not 0 < args.view_scale <= MAX_VIEW_SCALE:   # NaN too
        raise ValueError(f"--view-scale must be above 0 and at most {MAX_VIEW_SCALE:g}, got {args.view_scale}")
    if args.cameras is not None and args.cameras < 1:
        raise ValueError(f"--cameras must be 1 or more, got {args.cameras}")
    check_writable_folder(args.output)   # before the search: -o naming a file fails now, not after it
    config = load_config(args.params).resolved()
    problem = load_problem(args, up_of(config))
    if not problem.regions:
        raise ValueError(f"{problem.name}: no perch regions found ({problem.route})")
    result = optimise(problem.mesh, problem.regions, problem.target,
                      args.cameras if args.cameras is not None else config.num_cameras, config,
                      method=args.method or config.method,
                      seed=args.seed if args.seed is not None else config.seed)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    write_placements(out / "placements.yaml", problem, result, config)
    views = write_views(out, problem, result.placements, config, args.view_scale)
    print(result.message)
    print(f"wrote {out / 'placements.yaml'} and {len(views)} view(s) in {out}")
    return 0 if result.placements else 1


def write_placements(path: Path, problem, result, config) -> None:
    """Write the placements and scores as YAML."""
    import yaml

    from perch_common.outputs import atomic_path

    def plain(p):
        if problem.alignment is not None:  # back in the mesh file's own frame
            p = problem.alignment.placement_to_input(p)
        return {"drone_index": p.drone_index, "region_id": p.region_id,
                "drone_pose": np.round(p.drone_pose, 6).tolist(), "camera_pose": np.round(p.camera_pose, 6).tolist(),
                "pan_deg": round(math.degrees(p.pan), 3), "tilt_deg": round(math.degrees(p.tilt), 3),
                "zoom": p.zoom, "marginal_gain": round(p.marginal_gain, 6), "fitness": round(p.fitness, 6),
                "coverage": round(p.coverage, 6), "mean_uncertainty_m2": float(p.mean_uncertainty)}

    doc = {"mesh": problem.name, "regions": f"{len(problem.regions)} ({problem.route})",
           "frame_id": problem.alignment.input_frame if problem.alignment else problem.mesh.frame_id,
           "camera": config.camera.name, "fitness": round(result.fitness, 6), "coverage": round(result.coverage, 6),
           "mean_uncertainty_m2": float(result.mean_uncertainty), "upper_bound": float(result.upper_bound),
           "evaluations": int(result.evaluations), "seconds": round(result.seconds, 3),
           "message": result.message, "placements": [plain(p) for p in result.placements]}
    with atomic_path(path) as temporary:   # a failed write leaves the previous file whole
        temporary.write_text(yaml.safe_dump(doc, sort_keys=False))


def write_views(out: Path, problem, placements, config, scale: float) -> list[Path]:
    """Write each placed camera's simulated colour and depth views (PNG); returns the colour paths."""
    import cv2

    from perch_common.outputs import atomic_path
    from perch_placement.core import scene_for
    from perch_placement.render import render_view

    written = []
    # Views of an earlier run's further cameras would sit beside placements.yaml as if they were this run's.
    placed = {p.drone_index for p in placements}
    for stale in [*out.glob("view_*.png"), *out.glob("depth_*.png")]:
        index = stale.stem.split("_", 1)[1]
        if index.isdigit() and int(index) not in placed:
            stale.unlink()
    scene = scene_for(problem.mesh) if placements else None  # one BVH for every view
    for p in placements:
        rgb, depth = render_view(problem.mesh, p, config.camera, problem.target, scale=scale, scene=scene)
        colour_path = out / f"view_{p.drone_index}.png"
        for path, image in ((colour_path, rgb[:, :, ::-1]),
                            (out / f"depth_{p.drone_index}.png", np.clip(depth * 1000, 0, 65535).astype(np.uint16))):
            with atomic_path(path) as temporary:   # cv2 says False instead of raising: make it an error
                if not cv2.imwrite(str(temporary), image):
                    raise OSError(f"{path}: could not write the image")
        written.append(colour_path)
    return written
