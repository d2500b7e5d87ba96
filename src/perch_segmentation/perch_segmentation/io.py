"""Writing a segmentation to disk: surfaces as YAML or JSON, a mesh coloured by surface."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh, save_mesh
from perch_common.types import Surface
from perch_segmentation.render import label_colors

SURFACE_SUFFIXES = (".yaml", ".yml", ".json")


def surface_record(surface: Surface) -> dict:
    """A surface as plain data (lists and numbers)."""
    frame = surface.frame
    return {
        "id": int(surface.id),
        "surface_class": int(surface.surface_class),
        "area": float(surface.area),
        "rms_distance": float(surface.rms_distance),
        "mean_color": [float(c) for c in surface.mean_color],
        "frame": {name: [float(x) for x in getattr(frame, name)] for name in ("origin", "axis_u", "axis_v", "normal")},
        "boundary": [[np.round(np.asarray(ring, np.float64), 5).tolist() for ring in polygon]
                     for polygon in surface.boundary],
        "face_indices": np.asarray(surface.face_indices, np.int64).tolist(),
    }


def output_paths(out: str | Path) -> tuple[Path, Path]:
    """(surfaces file, coloured mesh) for OUT: a .yaml/.yml/.json file (mesh beside it) or a folder."""
    out = Path(out)
    if out.suffix.lower() in SURFACE_SUFFIXES:
        return out, out.with_name(out.stem + "_segments.ply")
    return out / "surfaces.yaml", out / "segments.ply"


def write_surfaces(path: str | Path, surfaces: list[Surface], source: str = "", frame_id: str = "map") -> Path:
    import yaml

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    document = {"source": source, "frame_id": frame_id, "surfaces": [surface_record(s) for s in surfaces]}
    if path.suffix.lower() == ".json":
        path.write_text(json.dumps(document))
    else:
        dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
        with path.open("w") as handle:
            yaml.dump(document, handle, Dumper=dumper, default_flow_style=None, sort_keys=False)
    return path


def write_colored_mesh(path: str | Path, mesh: Mesh, face_labels: np.ndarray) -> Path:
    """The mesh with each face coloured by its surface (grey: on none)."""
    return save_mesh(path, mesh, face_colors=label_colors(face_labels))
