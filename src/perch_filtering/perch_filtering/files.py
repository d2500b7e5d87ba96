"""Perch regions and removals as JSON files (and the regions as a coloured mesh) for the CLI.

Surfaces files have one format, perch_common.surfaces_file's: read and written through it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh, save_mesh
from perch_common.outputs import atomic_path
from perch_common.surfaces_file import write_surfaces
from perch_common.types import FilterRemoval, PerchRegion, PlaneFrame, SurfaceClass

CLASS_COLORS = {SurfaceClass.WALL: (60, 140, 230), SurfaceClass.CEILING: (240, 170, 40),
                SurfaceClass.FLOOR: (90, 190, 90), SurfaceClass.INTERMEDIATE: (200, 80, 200)}


def frame_dict(frame: PlaneFrame) -> dict:
    """A plane frame as plain lists."""
    return {k: np.round(getattr(frame, k), 9).tolist() for k in ("origin", "axis_u", "axis_v", "normal")}


def polygons_list(polygons: list) -> list:
    """Polygons with holes as plain nested lists."""
    return [[np.round(np.asarray(ring, np.float64), 6).tolist() for ring in poly] for poly in polygons]


def region_dict(r: PerchRegion) -> dict:
    """A perch region as plain data (without its mesh)."""
    return {"id": int(r.id), "source_surface": int(r.source_surface),
            "surface_class": SurfaceClass(r.surface_class).name.lower(), "area": float(r.area),
            "frame": frame_dict(r.frame), "polygons": polygons_list(r.polygons),
            "evidence": {k: float(v) for k, v in vars(r.evidence).items()}}


def removal_dict(r: FilterRemoval) -> dict:
    """A surface's per-filter removed areas as plain data."""
    return {k: (int(v) if k == "surface_id" else round(float(v), 6)) for k, v in vars(r).items()}


def write_result(out_dir: str | Path, result) -> dict[str, Path]:
    """regions.json (regions, removals, summary), surfaces.json (oriented input) and regions.ply."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"message": result.message, "seconds": result.seconds, "floor_height": result.floor_height,
               "floor_surfaces": result.floor_surfaces, "removed_m2": result.removed_area(),
               "regions": [region_dict(r) for r in result.regions],
               "removals": [removal_dict(r) for r in result.removals]}
    paths = {"regions": out / "regions.json", "surfaces": out / "surfaces.json"}
    with atomic_path(paths["regions"]) as temporary:   # a failed write leaves the previous file whole
        temporary.write_text(json.dumps(summary, indent=1))
    write_surfaces(paths["surfaces"], result.surfaces)
    if result.regions:
        paths["mesh"] = save_mesh(out / "regions.ply", *merged_regions(result.regions))
    return paths


def merged_regions(regions: list[PerchRegion]) -> tuple[Mesh, np.ndarray]:
    """All region meshes as one mesh, with face colours by class."""
    vertices, faces, colors, offset = [], [], [], 0
    for r in regions:
        vertices.append(r.mesh.vertices)
        faces.append(r.mesh.faces + offset)
        colors.append(np.tile(CLASS_COLORS.get(SurfaceClass(r.surface_class), (128, 128, 128)), (r.mesh.num_faces, 1)))
        offset += r.mesh.num_vertices
    return Mesh(np.concatenate(vertices), np.concatenate(faces)), np.concatenate(colors).astype(np.uint8)
