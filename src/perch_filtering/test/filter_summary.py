"""The filter's answers in a comparable form: region summaries and per-filter removals.

Used to show that a speed-up leaves the answers alone. `record` writes one JSON of the summaries of
every case (generated kinds on their ground-truth surfaces, real scans segmented); `compare` lists
what differs between two such files beyond tolerances. From a source checkout:

    .venv/bin/python src/perch_filtering/test/filter_summary.py record OUT.json [--cases room-1,...]
    .venv/bin/python src/perch_filtering/test/filter_summary.py compare BASE.json NEW.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from perch_common.conventions import FILTER_NAMES

AREA_TOL = 0.01       # m^2, or this share of the area, whichever is larger (a few 2 cm cells)
AREA_SHARE_TOL = 0.005
CENTROID_TOL = 0.02   # m
NORMAL_TOL = 1e-4
EVIDENCE_TOL = 1e-3

GENERATED = ["room-1", "l_shaped-2", "two_rooms-3", "apartment-4", "apartment-5:holes", "building-1",
             "building-1:mission"]
REAL = ["apartment.ply:+z", "icl_livingroom_kt2.obj:-y", "icl_office_kt2.obj:-y", "scans/quest_phanto_room.obj:+z"]


def summarise(result) -> dict:
    """Regions (surface, class, area, centroid, normal, evidence) and removals (per surface, per filter)."""
    regions = []
    for r in result.regions:
        tri = r.mesh.triangles()
        areas = r.mesh.face_areas()
        centroid = (tri.mean(axis=1) * areas[:, None]).sum(axis=0) / max(areas.sum(), 1e-12)
        regions.append({"surface": int(r.source_surface), "class": int(r.surface_class), "area": float(r.area),
                        "centroid": centroid.tolist(), "normal": r.frame.normal.tolist(),
                        "evidence": {k: float(v) for k, v in vars(r.evidence).items()}})
    regions.sort(key=lambda g: (g["surface"], round(g["centroid"][0], 3), round(g["centroid"][1], 3),
                                round(g["centroid"][2], 3)))
    removals = {str(m.surface_id): {name: float(getattr(m, name)) for name in ("area_total", *FILTER_NAMES, "area_kept")}
                for m in result.removals}
    return {"regions": regions, "removals": removals, "floor_height": float(result.floor_height),
            "area": float(sum(r.area for r in result.regions)), "message": result.message}


def _area_close(a: float, b: float) -> bool:
    return abs(a - b) <= max(AREA_TOL, AREA_SHARE_TOL * max(abs(a), abs(b)))


def compare(base: dict, new: dict) -> list[str]:
    """Differences between two case summaries beyond the tolerances (empty when equivalent)."""
    out = []
    if abs(base["floor_height"] - new["floor_height"]) > 1e-6:
        out.append(f"floor height {base['floor_height']:.4f} -> {new['floor_height']:.4f}")
    for sid, rb in base["removals"].items():
        rn = new["removals"].get(sid)
        if rn is None:
            out.append(f"surface {sid}: missing")
            continue
        for name, value in rb.items():
            if not _area_close(value, rn[name]):
                out.append(f"surface {sid} {name}: {value:.4f} -> {rn[name]:.4f} m2")
    if len(base["regions"]) != len(new["regions"]):
        out.append(f"regions {len(base['regions'])} -> {len(new['regions'])}")
        return out
    for i, (a, b) in enumerate(zip(base["regions"], new["regions"])):
        where = f"region {i} (surface {a['surface']})"
        if a["surface"] != b["surface"] or a["class"] != b["class"]:
            out.append(f"{where}: surface/class {a['surface']}/{a['class']} -> {b['surface']}/{b['class']}")
        if not _area_close(a["area"], b["area"]):
            out.append(f"{where}: area {a['area']:.4f} -> {b['area']:.4f}")
        if np.linalg.norm(np.subtract(a["centroid"], b["centroid"])) > CENTROID_TOL:
            out.append(f"{where}: centroid {a['centroid']} -> {b['centroid']}")
        if np.abs(np.subtract(a["normal"], b["normal"])).max() > NORMAL_TOL:
            out.append(f"{where}: normal {a['normal']} -> {b['normal']}")
        for k, v in a["evidence"].items():
            if abs(v - b["evidence"][k]) > EVIDENCE_TOL * max(1.0, abs(v)):
                out.append(f"{where}: evidence {k} {v:.4f} -> {b['evidence'][k]:.4f}")
    return out


def generated_case(name: str, cache: str | None = None):
    """(mesh, surfaces, target, up) of 'kind-seed[:holes]' on its ground-truth surfaces (as bench filter), or
    of 'kind-seed:mission' on the surfaces a mission segments from the cleaned mesh;
    kept in `cache` (a folder) when given: a building takes minutes to generate on a loaded machine."""
    import pickle
    from pathlib import Path

    from filtering_accuracy import filter_input_surfaces

    from perch_common.mesh import Mesh
    from perch_common.scene_generator import generate_scene

    path = Path(cache) / f"{name.replace(':', '_')}.pkl" if cache else None
    if path is not None and path.is_file():
        vertices, faces, surfaces, target, up = pickle.loads(path.read_bytes())
        return Mesh(vertices, faces), surfaces, target, up
    spec, _, extra = name.partition(":")
    kind, _, seed = spec.rpartition("-")
    scene = generate_scene(int(seed), kind, holes=3 if extra == "holes" else 0)
    if extra == "mission":  # what a mission's filter gets: the cleaned mesh, segmented
        from perch_reconstruction.cleaning import clean_mesh
        from perch_reconstruction.config import ReconstructionConfig
        from perch_segmentation.core import SegmentationConfig, segment_mesh

        mesh = clean_mesh(scene.mesh, -scene.up, ReconstructionConfig())  # generated scenes are z-up: no turn
        case = mesh, segment_mesh(mesh, SegmentationConfig()).surfaces, scene.target, scene.up
    else:
        case = scene.mesh, filter_input_surfaces(scene), scene.target, scene.up
    if path is not None:
        path.write_bytes(pickle.dumps((case[0].vertices, case[0].faces, *case[1:])))
    return case


def real_case(name: str):
    """(mesh, surfaces, target, up) of a shared scan turned z-up, segmented with the defaults; the target
    is the apartment's footprint or the middle half of the scan's floor plan, 1.2 m high."""
    from perch_common.data import shared_file
    from perch_common.mesh import load_mesh
    from perch_common.target import TargetVolume
    from perch_common.transforms import rotation_between
    from perch_segmentation.core import SegmentationConfig, segment_mesh

    path, _, up = name.partition(":")
    found = shared_file("meshes", *path.split("/"))
    if found is None:
        return None
    mesh = load_mesh(found)
    axis = {"+z": [0, 0, 1.0], "-y": [0, -1.0, 0], "+y": [0, 1.0, 0]}[up]
    if up != "+z":
        m = np.eye(4)
        m[:3, :3] = rotation_between(np.array(axis), np.array([0, 0, 1.0]))
        mesh = mesh.transformed(m)
    if path == "apartment.ply":
        target = TargetVolume.from_footprint_mesh(load_mesh(shared_file("meshes", "apartment_target.ply")), 1.2)
    else:
        lo, hi = np.percentile(mesh.vertices, 2, axis=0), np.percentile(mesh.vertices, 98, axis=0)
        mid, half = 0.5 * (lo + hi), 0.25 * (hi - lo)
        footprint = np.array([[mid[0] - half[0], mid[1] - half[1]], [mid[0] + half[0], mid[1] - half[1]],
                              [mid[0] + half[0], mid[1] + half[1]], [mid[0] - half[0], mid[1] + half[1]]])
        target = TargetVolume(footprint=footprint, base=float(lo[2]) + 0.3, height=1.2)
    surfaces = segment_mesh(mesh, SegmentationConfig()).surfaces
    return mesh, surfaces, target, np.array([0.0, 0.0, 1.0])


def run_case(name: str, config=None, cache: str | None = None) -> dict | None:
    """The summary of one case (None when its data is absent)."""
    from perch_filtering.core import FilterConfig, filter_surfaces

    case = real_case(name) if "." in name.partition(":")[0] else generated_case(name, cache)
    if case is None:
        return None
    mesh, surfaces, target, up = case
    start = time.perf_counter()
    result = filter_surfaces(mesh, surfaces, target, up, config or FilterConfig())
    summary = summarise(result)
    summary["seconds"] = time.perf_counter() - start
    return summary


def _setting(text: str) -> tuple[str, object]:
    """'name=value' with the value as JSON (numbers, true/false), else the string."""
    name, _, value = text.partition("=")
    try:
        return name, json.loads(value)
    except ValueError:
        return name, value


def main(argv=None) -> int:
    """record OUT [--cases A,B] | compare BASE NEW."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("out")
    rec.add_argument("--cases", default=",".join(GENERATED + REAL))
    rec.add_argument("--cache", help="folder keeping the generated scenes between runs")
    rec.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a FilterConfig setting")
    cmp_ = sub.add_parser("compare")
    cmp_.add_argument("base")
    cmp_.add_argument("new")
    args = p.parse_args(argv)
    from perch_filtering.core import FilterConfig
    if args.cmd == "record":
        out = {}
        for name in args.cases.split(","):
            try:
                summary = run_case(name, FilterConfig(**dict(_setting(kv) for kv in args.set)), args.cache)
            except Exception as exc:  # one case's failure (a scan segmentation refuses) is reported, not fatal
                print(f"{name}: failed: {exc}", file=sys.stderr)
                continue
            if summary is None:
                print(f"{name}: data absent, skipped", file=sys.stderr)
                continue
            out[name] = summary
            print(f"{name}: {len(summary['regions'])} regions, {summary['area']:.3f} m2, "
                  f"{summary['seconds']:.2f} s", file=sys.stderr)
            with open(args.out, "w") as fh:  # after every case: a long run keeps what it measured
                json.dump(out, fh, indent=1)
        return 0
    base, new = json.load(open(args.base)), json.load(open(args.new))
    bad = 0
    for name, summary in base.items():
        if name not in new:
            print(f"{name}: not in {args.new}")
            continue
        diffs = compare(summary, new[name])
        bad += bool(diffs)
        print(f"{name}: {'same' if not diffs else f'{len(diffs)} differences'} "
              f"({summary['seconds']:.2f} s -> {new[name]['seconds']:.2f} s)")
        for d in diffs[:20]:
            print("   ", d)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.path.insert(0, __file__.rsplit("/", 1)[0])
    sys.exit(main())
