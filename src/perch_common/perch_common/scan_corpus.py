"""The real-scan corpus and how an up estimate is scored on it (perch_operator.bench.scans runs it).

The corpus: the three older scans of ../shared/data/meshes and every row of meshes/scans/MANIFEST.tsv
(its true up column), each in its own frame (the file's header and format convention count) and in
the rotations y-up, y-down, tilt-25 and tilt-35 (perch_common.scan_orientations; a rotated copy is a
bare mesh: no header, the default convention, as a re-exported file would be). An estimate is right
within MAX_ANGLE_DEG with the right sign; `calibration` bins the stated confidence against that.
"""

from __future__ import annotations

import time

import numpy as np

MAX_ANGLE_DEG = 3.0
CAMERAS = 5
BINS = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0001)
APARTMENT_TARGET = ("apartment.ply", "apartment_target.ply", 1.2)


def manifest_scans(manifest) -> list[tuple[str, object, np.ndarray]]:
    """(file name, path, true up) of every row of a MANIFEST.tsv in the shared format (tab-separated,
    a header naming at least `file` and `up`; up '+y' or 'x,y,z'), files beside the manifest. A
    missing file, column or malformed up raises ValueError naming the row and the fix."""
    from pathlib import Path

    from perch_common.scan_orientations import _NAMED_AXES

    manifest = Path(manifest)
    if not manifest.is_file():
        raise ValueError(f"manifest {manifest}: not a file (give the path of a MANIFEST.tsv)")
    rows = manifest.read_text().splitlines()
    header = rows[0].split("\t") if rows else []
    if "file" not in header or "up" not in header:
        raise ValueError(f"manifest {manifest}: its first line must name the columns 'file' and 'up' "
                         "(tab-separated, as ../shared/data/meshes/scans/MANIFEST.tsv)")
    scans = []
    for number, row in enumerate(rows[1:], start=2):
        if not row.strip():
            continue
        cells = dict(zip(header, row.split("\t")))
        path = manifest.parent / cells.get("file", "")
        if not cells.get("file") or not path.is_file():
            raise ValueError(f"manifest {manifest} line {number}: file {cells.get('file')!r} not found beside it")
        text = cells.get("up", "").strip()
        try:
            up = np.array(_NAMED_AXES.get(text) or [float(c) for c in text.split(",")], np.float64)
        except ValueError:
            up = np.zeros(0)
        if up.shape != (3,) or not np.linalg.norm(up) > 0:
            raise ValueError(f"manifest {manifest} line {number}: up {text!r} is not '+x'..'-z' or 'x,y,z'")
        scans.append((cells["file"], path, up / np.linalg.norm(up)))
    return scans


def cases(only=(), rotations: bool = True, manifests=()):
    """(scan name, orientation, mesh, true up, file path or None, target) for every case of the corpus,
    plus every row of the given extra MANIFEST.tsv files (manifest_scans)."""
    from perch_common.data import shared_file
    from perch_common.mesh import load_mesh
    from perch_common.scan_orientations import CORPUS_ORIENTATIONS, corpus_scans, oriented

    extra = [scan for manifest in manifests for scan in manifest_scans(manifest)]
    for name, path, true_up in corpus_scans() + extra:
        if only and not any(text in name for text in only):
            continue
        mesh = load_mesh(path)
        target = None
        if name == APARTMENT_TARGET[0] and shared_file("meshes", APARTMENT_TARGET[1]):
            target = load_mesh(shared_file("meshes", APARTMENT_TARGET[1]))
        yield name, "own", mesh, np.asarray(true_up, np.float64), path, target
        for orientation in CORPUS_ORIENTATIONS if rotations else ():
            rotated, up, transform = oriented(mesh, true_up, orientation)
            yield name, orientation, rotated, up, None, target.transformed(transform) if target else None


def up_error(up: np.ndarray, true_up: np.ndarray) -> tuple[float, bool]:
    """(angle in degrees between the axes, whether the sign is right)."""
    cos = float(np.clip(np.asarray(up, np.float64) @ true_up / np.linalg.norm(up), -1.0, 1.0))
    return round(float(np.degrees(np.arccos(abs(cos)))), 3), cos > 0


def estimate_case(mesh, true_up: np.ndarray, path) -> dict:
    """The up estimate as `--up auto` makes it for this input (with its file's header when it has one)."""
    from perch_common.up_axis import choose_up, file_convention

    start = time.perf_counter()
    choice = choose_up("auto", mesh, file_convention(path))
    seconds = time.perf_counter() - start
    estimate = choice.estimate
    angle, sign = up_error(estimate.up, true_up)
    used_angle, used_sign = up_error(choice.up, true_up)
    return {"up_error_deg": angle, "sign_right": sign, "right": sign and angle <= MAX_ANGLE_DEG,
            "confidence": round(estimate.confidence, 3), "confident": estimate.confident,
            "up_source": choice.source, "auto_up_error_deg": used_angle, "auto_sign_right": used_sign,
            "considered": list(getattr(estimate, "considered", [])), "up_seconds": round(seconds, 3)}


def calibration(rows: list[dict]) -> dict:
    """Share of right estimates per confidence bin, and among those labelled confident."""
    table = []
    for low, high in zip(BINS[:-1], BINS[1:]):
        inside = [r for r in rows if low <= r["confidence"] < high]
        right = sum(r["right"] for r in inside)
        table.append({"confidence": f"[{low:.2f}, {min(high, 1.0):.2f}{']' if high > 1 else ')'}",
                      "cases": len(inside), "right": right,
                      "share_right": round(right / len(inside), 3) if inside else None})
    confident = [r for r in rows if r["confident"]]
    return {"bins": table, "confident": {"cases": len(confident), "right": sum(r["right"] for r in confident),
                                         "share_right": round(sum(r["right"] for r in confident) / len(confident), 3)
                                         if confident else None},
            "not_confident": {"cases": len(rows) - len(confident),
                              "right": sum(r["right"] for r in rows if not r["confident"])}}
