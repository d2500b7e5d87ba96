"""`perch mesh info FILE`: size, bounds, up axis (estimate, evidence, confidence) and problems of a mesh file."""

from __future__ import annotations

import json

from perch_common.mesh import add_units_arguments, inspect_mesh, load_mesh
from perch_common.mesh_health import inspect_health
from perch_common.up_axis import choose_up, file_convention


def register(sub) -> None:
    """Add `perch mesh info` to the CLI."""
    p = sub.add_parser("mesh", help="inspect mesh files")
    verbs = p.add_subparsers(dest="verb", metavar="VERB")
    info = verbs.add_parser("info", help="faces, bounds, up axis and problems found")
    info.add_argument("file")
    info.add_argument("--json", action="store_true", help="print JSON")
    add_units_arguments(info)
    info.set_defaults(func=_info)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def mesh_summary(path: str, scale: float = 1.0, shift: tuple[float, float, float] | None = None) -> dict:
    """Size, bounds, up estimate (with evidence and confidence) and problems (incl. implausible units) of a mesh file."""
    mesh = load_mesh(path, validate=False, scale=scale, shift=shift)
    problems = inspect_mesh(mesh)
    health = [] if problems.fatal else inspect_health(mesh, path=path).lines()   # soup, duplicates, windings, slivers
    summary = {"file": str(path), "vertices": mesh.num_vertices, "faces": mesh.num_faces,
               "vertex_colors": mesh.vertex_colors is not None,
               "problems": problems.fatal + [w for w in problems.warnings if "duplicate faces" not in w] + health}
    if not problems.fatal:
        lo, hi = mesh.bounds()
        convention = file_convention(path)
        estimate = choose_up("auto", mesh, convention).estimate   # as `--up auto` sees it (header included)
        summary.update({
            "bounds_min": lo.round(4).tolist(), "bounds_max": hi.round(4).tolist(),
            "size": (hi - lo).round(4).tolist(), "area_m2": round(float(mesh.face_areas().sum()), 3),
            "up_estimate": estimate.up.round(4).tolist(), "up_axis": estimate.axis_name(),
            "up_confidence": round(estimate.confidence, 3), "up_confident": estimate.confident,
            "up_evidence": estimate.evidence(), "file_convention_up": convention,
            "up_considered": estimate.considered, "windings_inverted": estimate.windings_inverted})
    return summary


def _info(args) -> int:
    s = mesh_summary(args.file, args.scale, args.shift)
    if args.json:
        print(json.dumps(s, indent=2))
        return 0 if "size" in s else 1   # a fatal problem (no bounds, no up estimate): exit 1 as below
    print(f"{s['file']}: {s['faces']} faces, {s['vertices']} vertices"
          f"{', vertex colours' if s['vertex_colors'] else ''}")
    if "size" in s:
        print(f"  bounds {s['bounds_min']} .. {s['bounds_max']} (size {s['size']} m, area {s['area_m2']} m^2)")
        verdict = "confident" if s["up_confident"] else (
            f"NOT confident: `--up auto` falls back to the file's convention {s['file_convention_up']}, and an "
            "--auto-accept mission stops; considered " + ", ".join(s["up_considered"]))
        print(f"  up axis {s['up_axis']} (estimate {s['up_estimate']}, confidence {s['up_confidence']:.2f}, {verdict})")
        for line in s["up_evidence"]:
            print(f"    {line}")
    print("  problems: " + ("; ".join(s["problems"]) if s["problems"] else "none"))
    return 0 if "size" in s else 1
