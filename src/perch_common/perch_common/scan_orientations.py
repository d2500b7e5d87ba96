"""The orientations a scan is tried in (z-up, y-up, y-down, x-up, two tilts) and the shared real scans'
true up, for the rotated-world tests and `perch bench up`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from perch_common.transforms import rotation_between

Z = np.array([0.0, 0.0, 1.0])


def _tilt(degrees: float, seed: int) -> np.ndarray:
    """A rotation by `degrees` about a seeded random axis."""
    axis = np.random.default_rng(seed).normal(size=3)
    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


# Rotation applied to a z-up scan: the copy's up is ORIENTATIONS[name] @ z. Rotations, not just
# up vectors, so that the copies differ in yaw too.
ORIENTATIONS: dict[str, np.ndarray] = {
    "z-up": np.eye(3),
    "y-up": Rotation.from_euler("x", -90, degrees=True).as_matrix(),
    "y-down": Rotation.from_euler("x", 90, degrees=True).as_matrix(),
    "x-up": Rotation.from_euler("y", 90, degrees=True).as_matrix(),
    "tilt-25": _tilt(25.0, seed=1),
    "tilt-35": _tilt(35.0, seed=2),
}

# The shared real scans (../shared/data/meshes) and their true up in the file's own frame.
REAL_SCANS: dict[str, np.ndarray] = {
    "apartment.ply": np.array([0.0, 0.0, 1.0]),
    "icl_livingroom_kt2.obj": np.array([0.0, -1.0, 0.0]),
    "icl_office_kt2.obj": np.array([0.0, -1.0, 0.0]),
}


def orientation_transform(true_up: np.ndarray, orientation: str) -> np.ndarray:
    """4x4 rotation taking a scan whose up is `true_up` into `orientation` (its up ends on ORIENTATIONS @ z)."""
    out = np.eye(4)
    out[:3, :3] = ORIENTATIONS[orientation] @ rotation_between(np.asarray(true_up, np.float64), Z)
    return out


def oriented(mesh, true_up: np.ndarray, orientation: str):
    """(the mesh rotated into `orientation`, its true up there, the 4x4 applied)."""
    transform = orientation_transform(true_up, orientation)
    return mesh.transformed(transform), transform[:3, :3] @ (np.asarray(true_up, np.float64)
                                                             / np.linalg.norm(true_up)), transform

# Rotations the corpus benchmark tries each scan in besides its own frame (`perch bench scans`).
CORPUS_ORIENTATIONS = ("y-up", "y-down", "tilt-25", "tilt-35")
MANIFEST = ("meshes", "scans", "MANIFEST.tsv")
_NAMED_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}


def corpus_scans() -> list[tuple[str, Path, np.ndarray]]:
    """Every real scan of the shared data with its true up: (name, path, up) for the REAL_SCANS found
    and each row of meshes/scans/MANIFEST.tsv (its `up` column: '+y' or 'x,y,z'). Absent files are left out."""
    from perch_common.data import shared_file

    scans = []
    for name, up in REAL_SCANS.items():
        path = shared_file("meshes", name)
        if path is not None:
            scans.append((name, path, up))
    manifest = shared_file(*MANIFEST)
    if manifest is None:
        return scans
    rows = manifest.read_text().splitlines()
    header = rows[0].split("\t") if rows else []
    for row in rows[1:]:
        cells = dict(zip(header, row.split("\t")))
        path = manifest.parent / cells.get("file", "")
        if not cells.get("file") or not path.is_file():
            continue
        text = cells["up"].strip()
        up = np.array(_NAMED_AXES.get(text) or [float(c) for c in text.split(",")], np.float64)
        scans.append((cells["file"], path, up / np.linalg.norm(up)))
    return scans
