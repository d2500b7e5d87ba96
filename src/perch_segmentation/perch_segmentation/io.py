"""A segmentation on disk: the surfaces file (perch_common.surfaces_file) and a mesh coloured by surface."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from perch_common.mesh import Mesh, save_mesh
from perch_common.surfaces_file import SURFACE_SUFFIXES
from perch_segmentation.render import label_colors


def output_paths(out: str | Path) -> tuple[Path, Path]:
    """(surfaces file, coloured mesh) for OUT: a .yaml/.yml/.json file (mesh beside it) or a folder."""
    out = Path(out)
    if out.suffix.lower() in SURFACE_SUFFIXES:
        return out, out.with_name(out.stem + "_segments.ply")
    return out / "surfaces.yaml", out / "segments.ply"


def write_colored_mesh(path: str | Path, mesh: Mesh, face_labels: np.ndarray) -> Path:
    """The mesh with each face coloured by its surface (grey: on none)."""
    return save_mesh(path, mesh, face_colors=label_colors(face_labels))
