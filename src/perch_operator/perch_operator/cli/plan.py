"""`perch plan` (one mission from a mesh, bag or generated scene) and `perch demo` (`make demo`)."""

from __future__ import annotations

import contextlib
import math
import sys
import time
from pathlib import Path

import numpy as np

from perch_common.cli_types import int_between, positive_float
from perch_common.errors import PerchError
from perch_common.mesh import add_units_arguments
from perch_common.up_axis import add_up_argument

DEMO_SEED = 7
MIN_FOOTPRINT_ACROSS = 0.05   # m: a target footprint smaller than this is a unit mistake, not a target


def register_plan(sub) -> None:
    """Add `perch plan` to the CLI."""
    p = sub.add_parser("plan", help="run one mission: where should the drones perch? (launches what it needs)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--mesh", type=Path, help="environment mesh (PLY/OBJ/GLB/glTF/STL), in any orientation (--up)")
    source.add_argument("--bag", type=Path, help="RGB-D bag to reconstruct first")
    source.add_argument("--scene", type=int, metavar="SEED", help="a generated scene with this seed")
    p.add_argument("--kind", default=None,
                   help="generated scene kind, with --scene (room, l_shaped, two_rooms, apartment, building, "
                        "multi_storey; default apartment)")
    p.add_argument("--target", default=None, metavar="SPEC",
                   help="floor (the cropped floor area, default for --mesh/--bag) | "
                        "box:CX,CY,CZ,SX,SY,SZ[,YAW_DEG] | several boxes joined by '+' (each weighted equally) | "
                        "FOOTPRINT_MESH[:HEIGHT] (extruded, default 1.2 m; read with --scale and --shift, and boxes are in "
                        "the frame they give); --scene defaults to the scene's own target")
    p.add_argument("--cameras", type=camera_count, default=0,
                   help="number of cameras (0: the placement node's default)")
    add_units_arguments(p, "--mesh and a footprint --target")
    p.add_argument("--seed", type=seed_int, default=-1, help="optimiser seed (negative: the node's default)")
    p.add_argument("--auto-accept", action="store_true", help="accept every proposal (else: perch operator ...)")
    add_up_argument(p, "the mesh (--mesh)")
    p.add_argument("--review-surfaces", type=int_between(0, 2 ** 32 - 1), default=0, metavar="N",  # 0: no review
                   help="before filtering, wait for `perch operator review ID [--reject ...]` on the N largest surfaces")
    _common(p)
    p.set_defaults(func=_plan)


def register_demo(sub) -> None:
    """Add `perch demo` to the CLI."""
    p = sub.add_parser("demo", help="the demo: a seeded apartment, auto-accepted, outputs in out/demo/")
    p.add_argument("--seed", type=int, default=DEMO_SEED, help="scene seed")
    p.add_argument("--cameras", type=camera_count, default=0,
                   help="number of cameras (0: the placement node's default)")
    from perch_common.launch import add_graph_arguments

    add_graph_arguments(p, "one-process")
    p.set_defaults(func=_demo, out=Path("out/demo"), config=None, param=[], timeout=600.0, no_launch=False,
                   quiet=False, overwrite=True)


def camera_count(text: str) -> int:
    """argparse type: cameras to place, 0 (the node's default) to MAX_CAMERAS (never silently changed:
    the goal's uint32 field would wrap 4294967296 to 0)."""
    import argparse

    from perch_common.request_validation import MAX_CAMERAS

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative; give 0 (the node's default) or more")
    if value > MAX_CAMERAS:
        raise argparse.ArgumentTypeError(f"{value} is too large; give 0 (the node's default) to {MAX_CAMERAS}")
    return value


def seed_int(text: str) -> int:
    """argparse type: a seed that fits the goal's int64 (negative: the node's default)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not -2 ** 63 <= value < 2 ** 63:
        raise argparse.ArgumentTypeError(f"{value} does not fit a 64-bit seed; give -1 (the node's default) "
                                         "or 0..9223372036854775807")
    return value


def _common(p) -> None:
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    p.add_argument("--config", type=Path, help="parameter file for the nodes it launches")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE",
                   help="parameter override for the nodes it launches (repeatable)")
    p.add_argument("--no-launch", action="store_true",
                   help="use the graph already running on this ROS domain (else: start the mission's own graph)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the outputs of an earlier mission in the output folder (else refused)")
    p.add_argument("--timeout", type=positive_float, default=900.0, help="mission time limit (s)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    from perch_common.launch import add_graph_arguments

    add_graph_arguments(p, "one-process")


def _box_target(part: str, spec: str):
    """One `box:CX,CY,CZ,SX,SY,SZ[,YAW_DEG]` of a --target spec."""
    from perch_common.target import TargetVolume

    if not part.startswith("box:"):
        raise ValueError(f"--target {spec}: several volumes are joined with '+' and each is a box:... ({part!r})")
    try:
        values = [float(v) for v in part[4:].split(",")]
    except ValueError:
        raise ValueError(f"--target {spec}: numbers expected after box:") from None
    if len(values) not in (6, 7):
        raise ValueError(f"--target {spec}: give CX,CY,CZ,SX,SY,SZ and optionally YAW_DEG per box")
    yaw = math.radians(values[6]) if len(values) == 7 else 0.0
    rotation = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    return TargetVolume(center=values[:3], size=values[3:6], rotation=rotation)


def parse_target(spec: str | None, scale: float = 1.0, shift: tuple[float, float, float] | None = None):
    """The TargetVolume message for --target (None: the scene's / crop's default). A footprint file is
    read as the mesh is (`scale`, `shift`: its --scale and --shift); boxes are in the mission's frame."""
    from perch_common.mesh import load_mesh
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.target import TargetVolume
    from perch_interfaces import msg as pm

    if spec is None or spec == "floor":
        return pm.TargetVolume(kind=pm.TargetVolume.KIND_DEFAULT)
    if spec.startswith("box:"):
        boxes = [_box_target(part, spec) for part in spec.split("+")]
        return target_to_msg(TargetVolume.union(boxes))
    path, height = spec, 1.2
    head, sep, tail = spec.rpartition(":")
    if sep and tail.replace(".", "", 1).isdigit():
        path, height = head, float(tail)
    # Sent as the mesh itself: the mission projects it along the true up (the mesh may not be z-up).
    footprint = load_mesh(Path(path), scale=scale, shift=shift)
    lo, hi = footprint.bounds()
    across = float(np.linalg.norm(hi - lo))
    if across < MIN_FOOTPRINT_ACROSS:   # a footprint in metres read with a millimetre mesh's --scale 0.001
        fix = (f"it is read with the mesh's --scale {scale:g}: give it in the mesh file's units, or the target as a "
               "box in metres (box:...)" if scale != 1.0 else "is it in metres? (or give a box: box:...)")
        raise ValueError(f"--target {path}: the footprint is {across:.3g} m across, smaller than anything to watch; {fix}")
    return pm.TargetVolume(kind=pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT, footprint=mesh_to_msg(footprint),
                           height=float(height))


def _plan(args) -> int:
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.transforms import parse_up_axis
    from perch_common.up_axis import file_convention
    from perch_interfaces.action import PlanPerches

    if args.kind is not None and args.scene is None:
        raise PerchError("--kind applies to --scene (a generated scene): a mesh or a bag is what it is")
    if not args.mesh and (args.scale != 1.0 or args.shift is not None):
        raise PerchError("--scale and --shift apply to --mesh (and a footprint --target read with it): a generated "
                         "scene and a bag's reconstruction are in metres")
    check_output_folder(args.out, args.overwrite, [args.mesh, args.bag, args.target and args.target.split(":")[0]])
    if args.up.strip().lower() != "auto":
        parse_up_axis(args.up)  # a malformed axis fails here, before anything is launched
    goal = PlanPerches.Goal(num_cameras=args.cameras, seed=args.seed, auto_accept=args.auto_accept,
                            review_surfaces=args.review_surfaces, up_axis=args.up,
                            up_convention=file_convention(args.mesh))
    goal.target = parse_target(args.target, args.scale, args.shift) if args.mesh else parse_target(args.target)
    describe = {"cameras_asked": args.cameras, "seed": args.seed}
    if args.mesh:
        from perch_common.mesh import load_mesh
        from perch_common.mesh_health import unreferenced_line, unreferenced_vertices

        mesh = load_mesh(args.mesh, scale=args.scale, shift=args.shift)
        lost = unreferenced_line(*unreferenced_vertices(mesh, args.mesh))   # only the file shows it for an OBJ
        if lost:
            print(f"perch: warning: {args.mesh}: {lost}", file=sys.stderr)
        goal.mesh = mesh_to_msg(mesh)
        describe["source"] = f"mesh {args.mesh}"
        describe["up"] = args.up
        if args.scale != 1.0 or args.shift is not None:   # the outputs' frame: file * scale + shift
            from perch_operator.outputs.mission_data import scaled_coordinates

            describe["scale"] = args.scale
            describe["shift"] = ",".join(f"{v:g}" for v in args.shift or (0.0, 0.0, 0.0))
            describe["coordinates"] = scaled_coordinates(args.scale, args.shift)
    elif args.bag:
        if not args.bag.exists():
            raise FileNotFoundError(f"{args.bag}: no such bag")
        goal.bag_path = str(args.bag.resolve())
        describe["source"] = f"bag {args.bag}"
    else:
        from perch_common.scene_generator import generate_scene

        args.kind = args.kind or "apartment"
        scene = generate_scene(args.scene, args.kind)
        goal.mesh = mesh_to_msg(scene.mesh)
        if args.target is None:
            goal.target = target_to_msg(scene.target)
        describe["source"] = f"generated {args.kind} scene, seed {args.scene}"
    return run_plan(goal, args, describe)


def check_output_folder(out: Path, overwrite: bool, inputs) -> None:
    """Refuse an output folder that is (or holds) an input, or holds an earlier mission without --overwrite."""
    from perch_common.outputs import (
        check_writable_folder,
        refuse_folder_holding_inputs,
        refuse_foreign_outputs,
        refuse_overwriting_inputs,
    )
    from perch_operator.cli.runner import OUTPUT_NAMES

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise PerchError(f"-o {out}: is a file; give a folder for the mission outputs")
    refuse_overwriting_inputs([out] + [out / n for n in OUTPUT_NAMES], inputs)
    refuse_folder_holding_inputs(out, inputs)
    # What Perch did not write is refused first, with or without --overwrite (which would not replace it).
    refuse_foreign_outputs(out, OUTPUT_NAMES)
    earlier = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if earlier and not overwrite:
        raise PerchError(f"-o {out}: holds the outputs of an earlier mission ({', '.join(earlier)}); "
                         "add --overwrite to replace them, or choose another folder")
    check_writable_folder(out)


def run_plan(goal, args, describe: dict) -> int:
    """Start the mission's own graph (or use the running one with --no-launch), run and record the
    mission, write the outputs, print the summary; SIGTERM/SIGHUP stop the nodes like Ctrl-C."""
    import rclpy

    from perch_common import namespace
    from perch_common.config import check_overrides
    from perch_common.launch import parse_overrides, use_perch_dds
    from perch_operator.cli.runner import (
        choose_domain,
        client_context,
        existing_perch_graph,
        graph_ros_args,
        mission_nodes,
        start_own_graph,
    )

    use_perch_dds(network=args.network or None)
    started = time.monotonic()
    launch = not args.no_launch
    if (args.param or args.config) and not launch:
        given = "-p" if args.param else "--config"
        raise PerchError(f"{given} with --no-launch: the running graph keeps the parameters it was started with; "
                         "set them on it (`ros2 param set /perch_placement num_cameras 3`, refused where a parameter "
                         "is read-only) or drop --no-launch to start a graph with them")
    check_overrides(parse_overrides(args.param), mission_nodes(), args.config, namespace.current())  # before anything starts
    domain = choose_domain() if launch else None
    in_process = launch and args.graph_mode == "one-process"
    ros_args = graph_ros_args(args.config, args.param, args.out / "logs") if in_process else None
    with client_context(ros_args, domain):
        node = rclpy.create_node("perch_plan")
        graph = None
        try:
            if launch:
                launch = not _use_running_graph(node, existing_perch_graph(node), domain, args.param)
            if launch:
                graph = start_own_graph(node, args.graph_mode, domain, args.config, args.param, args.out / "logs")
            return _mission_and_outputs(node, goal, args, describe, started)
        except KeyboardInterrupt:
            raise PerchError(f"interrupted; see {args.out}/FAILED when the mission had started") from None
        finally:
            if graph is not None:
                graph.stop()


def _use_running_graph(node, existing: tuple[list[str], list[str]], domain: int, overrides) -> bool:
    """True when a usable Perch graph runs on the user's domain (the mission then runs on it); raises
    PerchError when Perch nodes there cannot be used, or -p asks for parameters it does not have."""
    found, problems = existing
    where = f"ROS domain {domain}" + (f", namespace {node.get_namespace()}" if node.get_namespace() != "/" else "")
    if problems:
        raise PerchError(f"{where} already has Perch nodes this perch cannot use ({'; '.join(problems)}); stop "
                         "them, or give this mission another ROS_DOMAIN_ID or --namespace")
    if not found:
        return False
    if overrides:
        raise PerchError(f"a Perch graph already runs on {where}; -p cannot change its parameters (set them on "
                         "it with `ros2 param set`, or stop it and run perch plan again)")
    print(f"perch: using the Perch graph already running on {where} (its parameters)", file=sys.stderr)
    return True


def _mission_and_outputs(node, goal, args, describe: dict, started: float) -> int:
    from perch_operator.cli.runner import run_recorded_mission, summary_table, write_outputs

    outputs = run_recorded_mission(node, goal, args.out, progress=not args.quiet, timeout=args.timeout,
                                   describe=describe)
    result = outputs.result
    with deferred_interrupt() as interrupted:  # the mission is over: nothing left to cancel, finish the files
        write_outputs(outputs)
    if interrupted:
        print("perch: interrupted after the mission ended; its outputs were completed first", file=sys.stderr)
    if not result.success:
        raise PerchError(f"mission failed: {result.message} (reason in {args.out}/FAILED, recording {outputs.mcap})")
    print(f"\n{describe.get('source', 'mission')}: {result.message}")
    print(summary_table(result))
    if outputs.perches:
        print(outputs.perches)
    if outputs.removals:
        print(outputs.removals)
    print(f"outputs in {args.out}/: waypoints.yaml, run.mcap, run.rrd, report.html  "
          f"({time.monotonic() - started:.1f} s in all, mission {outputs.mission_seconds:.1f} s)")
    return 0


@contextlib.contextmanager
def deferred_interrupt():
    """Hold SIGINT off during the block (yields a list that gets an entry if one arrived)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    arrived: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: arrived.append(signum))
    try:
        yield arrived
    finally:
        signal.signal(signal.SIGINT, previous)


def _demo(args) -> int:
    """`make demo`: launch the graph, plan on the seeded apartment with auto-accept, print the summary."""
    from perch_common.outputs import MANIFEST_NAME, written_by_perch
    from perch_common.scene_generator import generate_scene
    from perch_operator.api.client import scene_goal

    started = time.monotonic()
    scene = generate_scene(args.seed, "apartment")
    goal = scene_goal(scene, args.cameras)
    print(f"perch demo: generated apartment (seed {args.seed}): {scene.mesh.num_faces:,} faces, "
          f"target {scene.target.volume():.1f} m^3", file=sys.stderr)
    earlier = sorted(written_by_perch(args.out)) if (args.out / MANIFEST_NAME).is_file() else []
    if earlier:   # the demo's own folder, replaced each run: said, so that nobody keeps work there unawares
        print(f"perch demo: replacing the earlier demo's outputs in {args.out}/ ({', '.join(earlier)}); copy them "
              "elsewhere first to keep them", file=sys.stderr)
    code = run_plan(goal, args, {"source": f"generated apartment scene, seed {args.seed}", "demo": True})
    print(f"perch demo: done in {time.monotonic() - started:.1f} s; open {args.out}/report.html "
          f"or `perch view {args.out}/run.rrd`")
    return code
