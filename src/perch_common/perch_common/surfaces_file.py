"""The pipeline's one surfaces file format: surfaces as YAML or JSON, written and read back.

Segmentation writes it (`perch segment`), filtering reads it and writes its oriented, classed copies
(`perch filter`), and people edit it by hand (a surface_class may be given by name)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from perch_common.types import PlaneFrame, Surface, SurfaceClass

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


def surface_from_record(record: dict) -> Surface:
    """The inverse of `surface_record`; surface_class may be its number or its name ("wall")."""
    cls = record.get("surface_class", 0)
    cls = SurfaceClass[cls.upper()] if isinstance(cls, str) else SurfaceClass(int(cls))
    frame = PlaneFrame(*(np.asarray(record["frame"][k], np.float64) for k in ("origin", "axis_u", "axis_v", "normal")))
    return Surface(id=int(record["id"]), frame=frame, area=float(record.get("area", 0.0)),
                   face_indices=np.asarray(record.get("face_indices", []), np.int64), surface_class=cls,
                   rms_distance=float(record.get("rms_distance", 0.0)),
                   mean_color=np.asarray(record.get("mean_color", [0, 0, 0]), np.float64),
                   boundary=[[np.asarray(ring, np.float64).reshape(-1, 2) for ring in polygon]
                             for polygon in record.get("boundary", [])])


def read_surfaces(path: str | Path) -> list[Surface]:
    """Surfaces from a file written by `write_surfaces` (.json, else YAML); {"surfaces": [...]} or a bare list.

    Raises ValueError naming the file when it cannot be read or a surface is malformed."""
    import yaml

    path = Path(path)
    try:
        text = path.read_text()
        if path.suffix.lower() == ".json":
            document = json.loads(text)
        else:
            document = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read surfaces ({exc})") from exc
    records = document.get("surfaces") if isinstance(document, dict) else document
    if not isinstance(records, list):
        raise ValueError(f"{path}: expected a list of surfaces or {{\"surfaces\": [...]}}")
    try:
        return [surface_from_record(record) for record in records]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed surface ({exc!r})") from exc


def write_surfaces(path: str | Path, surfaces: list[Surface], source: str = "", frame_id: str = "map") -> Path:
    """{"source", "frame_id", "surfaces": [surface_record...]} as JSON (.json suffix) or YAML."""
    import yaml

    from perch_common.outputs import atomic_path

    path = Path(path)
    document = {"source": source, "frame_id": frame_id, "surfaces": [surface_record(s) for s in surfaces]}
    with atomic_path(path) as temporary:   # a failed write leaves the previous file whole
        if path.suffix.lower() == ".json":
            temporary.write_text(json.dumps(document))
        else:
            dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
            with temporary.open("w") as handle:
                yaml.dump(document, handle, Dumper=dumper, default_flow_style=None, sort_keys=False)
    return path
