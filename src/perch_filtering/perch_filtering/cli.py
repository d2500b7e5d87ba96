"""`perch filter MESH --surfaces S --target-mesh T --target-height H -o OUT`: the filtering stage offline."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh, load_mesh
from perch_common.target import TargetVolume
from perch_common.up_axis import add_up_argument, up_for_file
from perch_filtering.config import FilterConfig


def register(sub) -> None:
    """Add `perch filter`: the filtering stage on a mesh and its surfaces."""
    p = sub.add_parser("filter", help="keep the surface regions where a drone can safely perch",
                       description="Run the filtering stage on a mesh and its segmented surfaces; writes "
                                   "OUT/regions.json (regions, per-filter removed area), OUT/surfaces.json "
                                   "(oriented, classed surfaces) and OUT/regions.ply.")
    p.add_argument("mesh", help="environment mesh, in any orientation (--up)")
    p.add_argument("--surfaces", required=True,
                   help="surfaces file (YAML or JSON, as written by `perch segment` or to OUT/surfaces.json), or 'segment' "
                        "to segment the mesh first with perch_segmentation")
    add_target_arguments(p)
    add_up_argument(p)
    p.add_argument("--config", default=None, help="parameter YAML (default: config/perch.yaml)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                   help="override one filter parameter, e.g. -p allow_floor:=true (repeatable)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.set_defaults(func=run)


def add_target_arguments(p: argparse.ArgumentParser) -> None:
    """Add the target volume options (footprint mesh or box)."""
    g = p.add_argument_group("target volume (one of)")
    g.add_argument("--target-mesh", help="footprint mesh, projected onto the floor and extruded")
    g.add_argument("--target-height", type=float, default=1.2, help="extrusion of --target-mesh (m)")
    g.add_argument("--target-box", nargs="+", type=float, metavar="V",
                   help="cx cy cz sx sy sz [yaw_deg]: a box (yaw about z)")


def target_from_args(args) -> TargetVolume:
    """The target volume the target options describe (raises ValueError naming the problem)."""
    if args.target_box:
        v = args.target_box
        if len(v) not in (6, 7):
            raise ValueError(f"--target-box takes 6 or 7 numbers (cx cy cz sx sy sz [yaw_deg]), got {len(v)}")
        if not (np.isfinite(v).all() and min(v[3:6]) > 0):   # a NaN yaw filtered on a box of NaNs
            raise ValueError(f"--target-box {' '.join(f'{x:g}' for x in v)}: give finite numbers and sizes above 0 (m)")
        yaw = np.radians(v[6]) if len(v) == 7 else 0.0
        rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
        return TargetVolume(center=v[:3], size=v[3:6], rotation=rot)
    if args.target_mesh:
        return TargetVolume.from_footprint_mesh(load_mesh(args.target_mesh), args.target_height)
    raise ValueError("give a target: --target-mesh PATH [--target-height H] or --target-box cx cy cz sx sy sz")


def load_config(path: str | None, overrides: list[str]) -> tuple[FilterConfig, str]:
    """The perch_filtering section of the parameter file (+ overrides) and the up_axis parameter."""
    from perch_common.config import apply_overrides, from_parameters, node_parameters

    params = node_parameters("perch_filtering", path)
    apply_overrides(params, overrides, [*FilterConfig.__dataclass_fields__, "up_axis"], "perch_filtering")
    return from_parameters(FilterConfig, params).validate(), str(params.get("up_axis", "+z"))


def segment_surfaces(mesh: Mesh) -> list:
    """Surfaces of a mesh by the segmentation stage with its defaults (`--surfaces segment`)."""
    from perch_segmentation.core import SegmentationConfig, segment_mesh

    return segment_mesh(mesh, SegmentationConfig()).surfaces


def run(args) -> int:
    """Run `perch filter`; writes regions.json, surfaces.json and regions.ply."""
    from perch_common.outputs import check_writable_folder, refuse_overwriting_inputs
    from perch_common.surfaces_file import read_surfaces
    from perch_common.work import command_budget
    from perch_filtering.core import filter_surfaces
    from perch_filtering.files import write_result

    out = Path(args.output)
    check_writable_folder(out)   # -o naming a file fails now, not after the filter ran
    refuse_overwriting_inputs([out] + [out / n for n in ("regions.json", "surfaces.json", "regions.ply")],
                              [args.mesh, args.surfaces if args.surfaces != "segment" else None, args.target_mesh,
                               args.config])
    config, _ = load_config(args.config, args.param)
    mesh = load_mesh(args.mesh)
    with command_budget("perch filter", mesh.num_faces):   # a soup is refused in under a minute, not after minutes
        surfaces = segment_surfaces(mesh) if args.surfaces == "segment" else read_surfaces(args.surfaces)
        target = target_from_args(args)
        up = up_for_file(args.up, mesh, args.mesh).up  # filtering takes any up: outputs stay in the mesh's frame
        result = filter_surfaces(mesh, surfaces, target, up, config)
    paths = write_result(Path(args.output), result)
    print(result.message)
    for name, path in paths.items():
        print(f"  {name}: {path}")
    removed = ", ".join(f"{k.replace('_', ' ')} {v:.2f}" for k, v in result.removed_area().items())
    print(f"  removed (m^2): {removed}; {result.seconds:.2f} s", file=sys.stderr)
    return 0
