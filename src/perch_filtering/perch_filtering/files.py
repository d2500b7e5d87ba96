"""Surfaces, perch regions and removals as JSON files (and the regions as a coloured mesh) for the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh, save_mesh
from perch_common.types import FilterRemoval, PerchRegion, PlaneFrame, Surface, SurfaceClass

CLASS_COLORS = {SurfaceClass.WALL: (60, 140, 230), SurfaceClass.CEILING: (240, 170, 40),
                SurfaceClass.FLOOR: (90, 190, 90), SurfaceClass.INTERMEDIATE: (200, 80, 200)}


def frame_dict(frame: PlaneFrame) -> dict:
    return {k: np.round(getattr(frame, k), 9).tolist() for k in ("origin", "axis_u", "axis_v", "normal")}


def frame_from_dict(data: dict) -> PlaneFrame:
    return PlaneFrame(*(np.asarray(data[k], np.float64) for k in ("origin", "axis_u", "axis_v", "normal")))


def polygons_list(polygons: list) -> list:
    return [[np.round(np.asarray(ring, np.float64), 6).tolist() for ring in poly] for poly in polygons]


def surface_dict(s: Surface) -> dict:
    return {"id": int(s.id), "surface_class": SurfaceClass(s.surface_class).name.lower(),
            "frame": frame_dict(s.frame), "area": float(s.area), "rms_distance": float(s.rms_distance),
            "mean_color": np.asarray(s.mean_color, np.float64).tolist(),
            "face_indices": np.asarray(s.face_indices, np.int64).tolist(), "boundary": polygons_list(s.boundary)}


def surface_from_dict(d: dict) -> Surface:
    cls = d.get("surface_class", 0)
    cls = SurfaceClass[cls.upper()] if isinstance(cls, str) else SurfaceClass(int(cls))
    return Surface(id=int(d["id"]), frame=frame_from_dict(d["frame"]), area=float(d.get("area", 0.0)),
                   face_indices=np.asarray(d.get("face_indices", []), np.int64), surface_class=cls,
                   rms_distance=float(d.get("rms_distance", 0.0)),
                   mean_color=np.asarray(d.get("mean_color", [0, 0, 0]), np.float64),
                   boundary=[[np.asarray(r, np.float64).reshape(-1, 2) for r in poly] for poly in d.get("boundary", [])])


def read_surfaces(path: str | Path) -> list[Surface]:
    """A JSON file holding {"surfaces": [...]} (or a bare list) in the layout of `surface_dict`."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read surfaces ({exc})") from exc
    items = data.get("surfaces") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise ValueError(f"{path}: expected a list of surfaces or {{\"surfaces\": [...]}}")
    try:
        return [surface_from_dict(d) for d in items]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed surface ({exc!r})") from exc


def write_surfaces(path: str | Path, surfaces: list[Surface]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"surfaces": [surface_dict(s) for s in surfaces]}))
    return path


def region_dict(r: PerchRegion) -> dict:
    return {"id": int(r.id), "source_surface": int(r.source_surface),
            "surface_class": SurfaceClass(r.surface_class).name.lower(), "area": float(r.area),
            "frame": frame_dict(r.frame), "polygons": polygons_list(r.polygons)}


def removal_dict(r: FilterRemoval) -> dict:
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
    paths["regions"].write_text(json.dumps(summary, indent=1))
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
