"""`perch scene generate`: a seeded procedural scene (mesh + per-face ground-truth labels)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from perch_common.errors import PerchError
from perch_common.mesh import mesh_output, save_mesh
from perch_common.scene_generator import KINDS, generate_scene


def register(sub) -> None:
    """Add `perch scene`: generate seeded scenes with their ground truth."""
    p = sub.add_parser("scene", help="procedural scenes with ground truth")
    verbs = p.add_subparsers(dest="verb", metavar="VERB")
    g = verbs.add_parser("generate", help="write a seeded scene mesh and its labels")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--kind", choices=KINDS, default="apartment")
    g.add_argument("--noise", type=float, default=0.0, help="vertex noise sigma (m)")
    g.add_argument("--holes", type=int, default=0, help="number of holes cut into walls")
    g.add_argument("--no-ceiling", action="store_true")
    g.add_argument("--no-furniture", action="store_true")
    g.add_argument("--resolution", type=float, default=None,
                   help="grid size (m; default 0.1, building and multi_storey 0.042)")
    g.add_argument("--clutter", type=int, default=0, help="small boxes scattered on the floors")
    g.add_argument("--floors", type=int, default=None,
                   help="storeys of a multi_storey building, 2-4 (default: drawn from the seed)")
    g.add_argument("-o", "--output", required=True, help="mesh file (.ply, .obj, .glb, .stl)")
    g.set_defaults(func=_generate)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def write_scene(scene, output: Path) -> dict:
    """Mesh at `output`, labels beside it as OUTPUT.labels.npz and a JSON summary."""
    save_mesh(output, scene.mesh)
    labels = output.with_suffix(".labels.npz")
    np.savez_compressed(labels, face_plane=scene.face_plane, face_class=scene.face_class,
                        world_from_scene=scene.world_from_scene)
    summary = {
        "mesh": str(output), "labels": str(labels), "kind": scene.kind, "seed": scene.seed,
        "faces": scene.mesh.num_faces, "planes": len(scene.planes), "furniture": len(scene.furniture),
        "target": {"center": scene.target.center.round(4).tolist(), "size": scene.target.size.round(4).tolist()},
        "targets": [{"center": v.center.round(4).tolist(), "size": v.size.round(4).tolist()}
                    for v in scene.target.volumes()],
        "plane_table": [{"id": p.id, "class": p.semantic_class.name.lower(), "area": round(p.area, 4),
                         "normal": p.normal.round(4).tolist()} for p in scene.planes],
    }
    output.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    return summary


def _generate(args) -> int:
    mesh_output(args.output)
    for option, value, low in (("--noise", args.noise, 0.0), ("--holes", args.holes, 0), ("--clutter", args.clutter, 0)):
        if not value >= low:   # NaN too; a negative count or noise was used as none, or failed inside numpy
            raise PerchError(f"{option} {value}: give {low} or more")
    scene = generate_scene(args.seed, args.kind, noise=args.noise, holes=args.holes,
                           ceiling=not args.no_ceiling, furniture=not args.no_furniture,
                           resolution=args.resolution, clutter=args.clutter, floors=args.floors)
    s = write_scene(scene, Path(args.output))
    print(f"{s['mesh']}: {s['kind']} seed {s['seed']}, {s['faces']} faces, {s['planes']} planes, "
          f"{s['furniture']} furniture items; labels in {s['labels']}")
    return 0
