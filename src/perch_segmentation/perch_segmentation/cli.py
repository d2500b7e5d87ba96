"""`perch segment MESH -o OUT`: run the segmentation stage on a mesh file."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from perch_common.config import ConfigError, apply_overrides, default_config_path, from_parameters, node_parameters
from perch_common.mesh import add_units_arguments, load_mesh
from perch_common.up_axis import add_up_argument


def register(sub) -> None:
    """Add `perch segment`: split a mesh into planar surfaces, write the surfaces file."""
    parser = sub.add_parser(
        "segment", help="split a room mesh into planar surfaces",
        description="Run the segmentation stage on MESH; write the surfaces (YAML or JSON) and a mesh "
                    "coloured by surface. Parameters come from config/perch.yaml (perch_segmentation).")
    parser.add_argument("mesh", type=Path, help="mesh file (.ply .obj .glb .stl .off)")
    parser.add_argument("-o", "--output", type=Path, required=True,
                        help="a .yaml/.yml/.json file (the coloured mesh goes beside it as *_segments.ply) "
                             "or a folder (surfaces.yaml and segments.ply)")
    parser.add_argument("--config", type=Path, default=None, help="parameter file (default: config/perch.yaml)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                        help="override a parameter, e.g. -p use_color:=false (repeatable)")
    add_up_argument(parser)
    parser.add_argument("--png", type=Path, default=None, help="also render the coloured result to this PNG")
    add_units_arguments(parser)
    parser.set_defaults(func=run)


def load_config(config_path: Path | None, overrides: list[str]):
    """The segmentation settings of a parameter file with -p NAME=VALUE overrides."""
    from perch_segmentation.core import SegmentationConfig

    try:
        params = node_parameters("perch_segmentation", config_path or default_config_path())
    except ConfigError:
        if config_path is not None:
            raise
        params = {}  # no workspace config: the defaults
    apply_overrides(params, overrides, SegmentationConfig.__dataclass_fields__, "perch_segmentation")
    return from_parameters(SegmentationConfig, params)


def run(args: argparse.Namespace) -> int:
    """Run `perch segment`; writes the surfaces file and a coloured mesh."""
    from perch_common.errors import PerchError
    from perch_common.outputs import refuse_overwriting_inputs
    from perch_common.surfaces_file import write_surfaces
    from perch_common.work import command_budget
    from perch_segmentation.core import segment_mesh
    from perch_segmentation.io import output_paths, write_colored_mesh

    surfaces_path, mesh_path = output_paths(args.output)
    refuse_overwriting_inputs([args.output, surfaces_path, mesh_path, args.png], [args.mesh, args.config])
    if surfaces_path.parent == args.output and args.output.exists() and not args.output.is_dir():
        raise PerchError(f"-o {args.output}: is an existing file; give a .yaml/.json file or a folder")
    if args.png is not None and args.png.suffix.lower() != ".png":   # checked before the surfaces are written
        raise PerchError(f"--png {args.png}: give a file name ending in .png")
    config = load_config(args.config, args.param)
    mesh = load_mesh(args.mesh, scale=args.scale, shift=args.shift)
    if not any(p.split(":=")[0].strip() == "up_axis" for p in args.param):
        # Segmentation takes any up direction: the surfaces stay in the mesh's own frame.
        from dataclasses import replace

        from perch_common.up_axis import up_for_file

        up = up_for_file(args.up, mesh, args.mesh).up
        config = replace(config, up_axis=" ".join(f"{c:.9f}" for c in up))
    started = time.perf_counter()
    with command_budget("perch segment", mesh.num_faces):   # a soup is refused in under a minute, not after minutes
        result = segment_mesh(mesh, config)
    seconds = time.perf_counter() - started
    write_surfaces(surfaces_path, result.surfaces, source=str(args.mesh), frame_id=mesh.frame_id)
    write_colored_mesh(mesh_path, mesh, result.face_labels)
    area = sum(s.area for s in result.surfaces)
    print(f"{len(result.surfaces)} surfaces ({area:.1f} m^2 of {mesh.face_areas().sum():.1f} m^2) from "
          f"{mesh.num_faces} faces in {seconds:.2f} s")
    print(f"surfaces: {surfaces_path}\ncoloured mesh: {mesh_path}")
    if args.png:
        from perch_common.transforms import parse_up_axis
        from perch_segmentation.render import render_segmentation

        print(f"picture: {render_segmentation(mesh, result.face_labels, args.png, parse_up_axis(config.up_axis))}")
    return 0
