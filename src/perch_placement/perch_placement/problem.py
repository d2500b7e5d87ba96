"""Placement problems from command-line arguments: a mesh file with a target, or a generated scene."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from perch_common.config import load_node_config
from perch_common.mesh import Mesh, load_mesh
from perch_common.target import TargetVolume
from perch_common.transforms import parse_up_axis
from perch_placement.config import PlacementConfig
from perch_placement.scenes import regions_for


@dataclass
class Problem:
    name: str
    mesh: Mesh
    regions: list
    target: TargetVolume
    route: str   # how the regions were found


def add_problem_arguments(parser: argparse.ArgumentParser, mesh_positional: bool) -> None:
    if mesh_positional:
        parser.add_argument("mesh", nargs="?", help="environment mesh (PLY/OBJ/GLB/STL), z up")
    else:
        parser.add_argument("--mesh", help="environment mesh (PLY/OBJ/GLB/STL), z up")
    parser.add_argument("--target", "--target-mesh", dest="target_mesh",
                        help="target footprint mesh, extruded upwards by --target-height")
    parser.add_argument("--target-height", type=float, default=1.2, help="footprint extrusion (m)")
    parser.add_argument("--target-box", type=float, nargs=6, metavar=("CX", "CY", "CZ", "SX", "SY", "SZ"),
                        help="axis-aligned target box: centre and size (m)")
    parser.add_argument("--scene", type=int, help="use generated scene SEED instead of a mesh")
    parser.add_argument("--scene-kind", default="apartment", help="room | l_shaped | two_rooms | apartment")
    parser.add_argument("--regions", default="filtered", choices=("filtered", "unfiltered"),
                        help="perch regions from segmentation+filtering, or every wall/ceiling surface")
    parser.add_argument("--params", help="ROS parameter file (default: config/perch.yaml)")


def load_config(path: str | None) -> PlacementConfig:
    """The perch_placement section of the parameter file (defaults where absent)."""
    return load_node_config(PlacementConfig, "perch_placement", path)


def load_problem(args: argparse.Namespace, up=(0.0, 0.0, 1.0)) -> Problem:
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
    target = _target(args)
    if target is None:
        raise ValueError("give the target: --target FOOTPRINT_MESH [--target-height H] or --target-box ...")
    regions = regions_for(mesh, target, None, up, args.regions)
    return Problem(str(args.mesh), mesh, regions, target, args.regions)


def _target(args) -> TargetVolume | None:
    if args.target_mesh:
        return TargetVolume.from_footprint_mesh(load_mesh(args.target_mesh), args.target_height)
    if args.target_box:
        c, s = np.array(args.target_box[:3]), np.array(args.target_box[3:])
        return TargetVolume(center=c, size=s)
    return None


def up_of(config: PlacementConfig) -> np.ndarray:
    return parse_up_axis(config.up_axis)
