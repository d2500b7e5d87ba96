"""The filter alone, two source trees on one input: how #25's "filter >= 3x faster than 57af165" is measured.

    .venv/bin/python tools/filter_ab.py --capture building1.pkl            # a mission's filter input
    git worktree add ../before 57af165
    .venv/bin/python tools/filter_ab.py --input building1.pkl --out ab.json ../before .

--capture runs `perch bench mission --scene 1 --kind building --cameras 20` (or --scene/--kind/--cameras)
with this tree in a one-process graph and pickles the filter stage's first request as its core receives it
(the cleaned, cropped, segmented and gravity-aligned mesh, its surfaces, the target and up). The A/B then
runs, for each tree in turn (interleaved, --processes per tree), a fresh process that imports that tree's
sources, sets itself up as Perch's entry points do where the tree can (limit_threads, tune_memory,
KEEP_FREED_MEMORY), builds the ray scene outside the timing (as `perch bench filter`), and times a first
call and two repeats with default settings. It prints each process's line and the medians (first call,
repeats, CPU with the split's child) and their ratio. The pickle holds this tree's classes: both trees
must define Mesh, Surface and TargetVolume alike (true from 57af165 to now). Run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

CAPTURE = r'''
import pickle, sys
out, scene, kind, cameras = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
import perch_filtering.node as node
original = node.filter_surfaces
captured = []
def capturing(mesh, surfaces, target, up, config=None, *args, **kwargs):
    if not captured:
        with open(out, "wb") as f:
            pickle.dump(dict(vertices=mesh.vertices, faces=mesh.faces, viewpoints=mesh.viewpoints,
                             frame_id=mesh.frame_id, surfaces=surfaces, target=target, up=up), f)
        captured.append(True)
        print(f"captured: {mesh.num_faces} faces, {len(surfaces)} surfaces", file=sys.stderr)
    return original(mesh, surfaces, target, up, config, *args, **kwargs)
node.filter_surfaces = capturing
from perch_common.cli import main
sys.argv = ["perch", "bench", "mission", "--scene", scene, "--kind", kind, "--cameras", cameras,
            "--graph-mode", "one-process", "--json"]
code = main()
sys.exit(code if captured else 3)
'''

TIMED = r'''
import contextlib, json, pickle, resource, sys, time
try:
    from perch_common.threads import limit_threads
    limit_threads()
except ImportError:
    pass
try:
    from perch_common.memory import KEEP_FREED_MEMORY, tune_memory
    tune_memory()
except ImportError:
    KEEP_FREED_MEMORY = contextlib.nullcontext()
from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_filtering.core import FilterConfig, filter_surfaces
given = pickle.load(open(sys.argv[1], "rb"))
mesh = Mesh(given["vertices"], given["faces"], frame_id=given["frame_id"], viewpoints=given["viewpoints"])
RayScene(mesh)   # Embree's one-off initialisation is not the stage's (perch bench filter does the same)
times = []
for _ in range(3):
    start = time.perf_counter()
    with KEEP_FREED_MEMORY:
        result = filter_surfaces(mesh, given["surfaces"], given["target"], given["up"], FilterConfig())
    times.append(time.perf_counter() - start)
own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps(dict(times=times, regions=len(result.regions), area_m2=sum(r.area for r in result.regions),
                      cpu_s=own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime,
                      phases=dict(result.timings) if isinstance(result.timings, dict) else {})))
'''


def tree_path(tree: Path) -> str:
    """PYTHONPATH that imports a tree's pure-Python packages (its built interfaces are not needed)."""
    src = tree / "src"
    if not src.is_dir():
        raise SystemExit(f"{tree}: no src/ folder: give the root of a Perch checkout or worktree")
    return os.pathsep.join(str(p) for p in sorted(src.iterdir()) if p.is_dir() and p.name != "perch_interfaces")


def capture(out: Path, args) -> None:
    """Pickle the filter request of one generated-scene mission of this tree."""
    env = dict(os.environ, PYTHONPATH=tree_path(Path(__file__).resolve().parents[1]))
    done = subprocess.run([sys.executable, "-c", CAPTURE, str(out), str(args.scene), args.kind, str(args.cameras)],
                          env=env, stdout=subprocess.DEVNULL)
    if done.returncode:
        raise SystemExit(f"capture failed (exit {done.returncode}); its output is above")


def run_ab(inputs: Path, trees: list[Path], processes: int) -> dict:
    """Fresh processes per tree, interleaved; each line as it ends, then the medians and ratio."""
    runs: list[dict] = []
    for _ in range(processes):
        for tree in trees:
            env = dict(os.environ, PYTHONPATH=tree_path(tree))
            done = subprocess.run([sys.executable, "-c", TIMED, str(inputs)], env=env, capture_output=True, text=True)
            if done.returncode:
                raise SystemExit(f"{tree}: the timed process failed:\n{done.stderr[-3000:]}")
            line = dict(json.loads(done.stdout.strip().splitlines()[-1]), tree=str(tree), load=os.getloadavg()[0])
            print(json.dumps(line), flush=True)
            runs.append(line)
    summary: dict = {}
    for tree in map(str, trees):
        mine = [r for r in runs if r["tree"] == tree]
        summary[tree] = dict(first_s=statistics.median(r["times"][0] for r in mine),
                             repeats_s=statistics.median(t for r in mine for t in r["times"][1:]),
                             cpu_s=statistics.median(r["cpu_s"] for r in mine),
                             regions=mine[0]["regions"], area_m2=mine[0]["area_m2"])
    if len(trees) == 2:
        before, after = summary[str(trees[0])], summary[str(trees[1])]
        summary["ratio"] = dict(first=before["first_s"] / after["first_s"], repeats=before["repeats_s"] / after["repeats_s"])
    return dict(runs=runs, summary=summary)


def main() -> int:
    """Capture a mission's filter input, or time the filter of each tree on it."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("trees", nargs="*", type=Path, help="source trees to time (first: the baseline)")
    parser.add_argument("--capture", type=Path, help="write the filter input of a mission by this tree here")
    parser.add_argument("--input", type=Path, help="filter input written by --capture")
    parser.add_argument("--scene", type=int, default=1)
    parser.add_argument("--kind", default="building")
    parser.add_argument("--cameras", type=int, default=20)
    parser.add_argument("--processes", type=int, default=3, help="fresh processes per tree")
    parser.add_argument("--out", type=Path, help="also write the runs and medians here (JSON)")
    args = parser.parse_args()
    if args.capture:
        capture(args.capture, args)
    if not args.trees:
        return 0
    inputs = args.input or args.capture
    if inputs is None:
        parser.error("give --input FILE (or --capture FILE) with the trees")
    result = run_ab(inputs, args.trees, args.processes)
    print(json.dumps(result["summary"], indent=1))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
