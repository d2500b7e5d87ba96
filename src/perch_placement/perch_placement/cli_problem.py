"""Placement problems for `perch place` and `perch bench placement`: a mesh file with a target, or a
generated scene, and its perch regions (through the segmentation and filtering stages, or every
wall/ceiling surface unfiltered)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from perch_common.cli_types import non_negative_int, positive_float
from perch_common.config import load_node_config
from perch_common.conventions import DEFAULT_CLASS_ANGLE_DEG, surface_class
from perch_common.frames import Alignment
from perch_common.mesh import Mesh, load_mesh
from perch_common.polygons import faces_outline
from perch_common.target import TargetVolume
from perch_common.transforms import parse_up_axis
from perch_common.types import PerchRegion, Surface, SurfaceClass
from perch_common.up_axis import add_up_argument, up_for_file
from perch_placement.config import PlacementConfig


@dataclass
class Problem:
    """A named placement problem: the environment mesh, its perch regions and the target."""

    name: str
    mesh: Mesh
    regions: list
    target: TargetVolume
    route: str   # how the regions were found
    # mesh, regions and target are gravity-aligned; this takes them to the mesh file's own frame
    alignment: Alignment | None = None


def add_problem_arguments(parser: argparse.ArgumentParser, mesh_positional: bool) -> None:
    """Add the mesh/scene, target, regions-route and parameter-file options to a parser."""
    if mesh_positional:
        parser.add_argument("mesh", nargs="?", help="environment mesh (PLY/OBJ/GLB/STL), any orientation (--up)")
    else:
        parser.add_argument("--mesh", help="environment mesh (PLY/OBJ/GLB/STL), any orientation (--up)")
    add_up_argument(parser, "the mesh file and the target given with it")
    parser.add_argument("--target", "--target-mesh", dest="target_mesh",
                        help="target footprint mesh, extruded upwards by --target-height")
    parser.add_argument("--target-height", type=positive_float, default=1.2, help="footprint extrusion (m, > 0)")
    parser.add_argument("--target-box", type=float, nargs=6, metavar=("CX", "CY", "CZ", "SX", "SY", "SZ"),
                        help="axis-aligned target box: centre and size (m)")
    parser.add_argument("--scene", type=non_negative_int, metavar="SEED",
                        help="use generated scene SEED (>= 0) instead of a mesh")
    parser.add_argument("--scene-kind", default="apartment",
                        help="room | l_shaped | two_rooms | apartment | building | multi_storey")
    parser.add_argument("--regions", default="filtered", choices=("filtered", "unfiltered"),
                        help="perch regions from segmentation+filtering, or every wall/ceiling surface")
    parser.add_argument("--params", help="ROS parameter file (default: config/perch.yaml)")


def load_config(path: str | None) -> PlacementConfig:
    """The perch_placement section of the parameter file (defaults where absent)."""
    return load_node_config(PlacementConfig, "perch_placement", path)


def load_problem(args: argparse.Namespace, up=(0.0, 0.0, 1.0)) -> Problem:
    """The problem the parsed arguments describe (raises ValueError naming what is missing)."""
    up = np.asarray(up, np.float64)
    if args.scene is not None:
        from perch_common.scene_generator import generate_scene

        scene = generate_scene(args.scene, args.scene_kind)
        target = _target(args) or scene.target
        surfaces = scene.ground_truth_surfaces()
        regions = regions_for(scene.mesh, target, surfaces, up, args.regions)
        return Problem(f"scene {args.scene_kind} {args.scene}", scene.mesh, regions, target, args.regions)
    if not args.mesh:
        raise ValueError("give a mesh file or --scene SEED")
    mesh = load_mesh(args.mesh)
    # Placement works gravity-aligned (the target footprint is extruded along up); placements are
    # written back in the file's frame (Problem.alignment).
    choice = up_for_file(getattr(args, "up", "+z"), mesh, args.mesh)
    alignment = Alignment(mesh.frame_id, choice.estimate.aligned_rotation(choice.up))
    mesh = mesh.transformed(alignment.to_aligned())
    target = _target(args, alignment)
    if target is None:
        raise ValueError("give the target: --target FOOTPRINT_MESH [--target-height H] or --target-box ...")
    regions = regions_for(mesh, target, None, np.array([0.0, 0.0, 1.0]), args.regions)
    return Problem(str(args.mesh), mesh, regions, target, args.regions, alignment)


def _target(args, alignment: Alignment | None = None) -> TargetVolume | None:
    """The target from the arguments, in the gravity-aligned frame when an alignment is given."""
    to_aligned = np.eye(4) if alignment is None else alignment.to_aligned()
    if args.target_mesh and args.target_box:   # the box was ignored without a word
        raise ValueError("give one target: --target FOOTPRINT_MESH or --target-box, not both")
    if args.target_box and not (np.isfinite(args.target_box).all() and np.min(args.target_box[3:]) > 0):
        raise ValueError(f"--target-box {' '.join(f'{v:g}' for v in args.target_box)}: give a finite centre and "
                         "sizes above 0 (m)")
    if args.target_mesh:
        footprint = load_mesh(args.target_mesh).transformed(to_aligned)
        return TargetVolume.from_footprint_mesh(footprint, args.target_height)
    if args.target_box:
        c, s = np.array(args.target_box[:3]), np.array(args.target_box[3:])
        return TargetVolume(center=to_aligned[:3, :3] @ c, size=s, rotation=to_aligned[:3, :3])
    return None


def up_of(config: PlacementConfig) -> np.ndarray:
    """The configured up direction as a unit vector."""
    return parse_up_axis(config.up_axis)


def unfiltered_regions(mesh: Mesh, surfaces: list[Surface], up=(0.0, 0.0, 1.0), min_area: float = 0.5,
                       towards: np.ndarray | None = None,
                       class_angle_deg: float = DEFAULT_CLASS_ANGLE_DEG) -> list[PerchRegion]:
    """Every surface that does not face up as a perch region (no filtering), classed by the class angle.

    A stand-in for the filtering stage (benchmarks, tests). Generated scenes' surfaces already face
    free space; segmented ones are unoriented, so give `towards` (the target centre) to turn each
    normal towards it."""
    up = np.asarray(up, np.float64)
    regions = []
    for s in surfaces:
        frame, polygons = s.frame, s.boundary
        if towards is not None and (np.asarray(towards) - frame.origin) @ frame.normal < 0:
            # The flipped frame swaps u and v, so the outline's coordinates swap too.
            frame, polygons = frame.flipped(), [[ring[:, ::-1] for ring in poly] for poly in polygons]
        cls = surface_class(frame.normal, up, class_angle_deg)
        upward = cls == SurfaceClass.FLOOR or (cls == SurfaceClass.INTERMEDIATE and frame.normal @ up > 0)
        if s.area < min_area or upward:  # floors and upward-facing tops are not perches here
            continue
        polygons = polygons or faces_outline(frame, mesh.triangles()[s.face_indices])
        regions.append(PerchRegion(len(regions), s.id, cls, frame, polygons,
                                   mesh.submesh(s.face_indices), float(s.area)))
    return regions


def regions_for(mesh: Mesh, target, surfaces: list[Surface] | None = None, up=(0.0, 0.0, 1.0),
                route: str = "filtered") -> list[PerchRegion]:
    """Perch regions of a mesh. route "filtered": segmentation (unless `surfaces` are given) and the
    filtering stage; "unfiltered": every wall/ceiling surface (segmented unless given)."""
    if route == "filtered":
        return filtered_regions(mesh, target, up, surfaces)
    if route != "unfiltered":
        raise ValueError(f"regions route '{route}': use filtered or unfiltered")
    if surfaces is None:
        from perch_segmentation.core import segment_mesh

        surfaces = segment_mesh(mesh).surfaces
        return unfiltered_regions(mesh, surfaces, up, towards=target.centroid())
    return unfiltered_regions(mesh, surfaces, up)


def filtered_regions(mesh: Mesh, target: TargetVolume, up=(0.0, 0.0, 1.0), surfaces=None) -> list:
    """Segment the mesh (unless surfaces are given) and filter the surfaces into perch regions."""
    from perch_filtering.core import filter_surfaces
    from perch_segmentation.core import segment_mesh

    if surfaces is None:
        surfaces = segment_mesh(mesh).surfaces
    return filter_surfaces(mesh, surfaces, target, np.asarray(up, np.float64)).regions
