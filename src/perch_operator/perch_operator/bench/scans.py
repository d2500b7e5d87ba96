"""`perch bench scans`: Perch on every real scan of the shared data, as a new user runs it.

    perch bench scans --json                      # every scan, own frame + 4 rotations, 5 cameras
    perch bench scans --only holo2 --no-rotations # one scan family in its own frame
    perch bench scans --no-missions               # the up estimate alone (seconds, not minutes)
    perch bench scans --manifest DIR/MANIFEST.tsv # add the scans of another folder to the corpus

The corpus: the three older scans of ../shared/data/meshes and every row of meshes/scans/MANIFEST.tsv
(its true up column), each in its own frame (the file's header and format convention count) and in
the rotations y-up, y-down, tilt-25 and tilt-35 (perch_common.scan_orientations; a rotated copy is a
bare mesh: no header, the default convention, as a re-exported file would be).

Per scan and orientation: the up estimate's error (deg), sign and stated confidence, then one mission
with default settings, `--up auto`, auto-accept and 5 cameras on one graph hosted in this process
(started once): whether it placed anything or stopped (and why), the up it planned on, cameras
placed, and per perch Perch's own safety evidence (every PerchEvidence field of its proposal), the
project checker's verdict and the perch's observed-space share when the installed packages provide
them (null with a note otherwise), and seconds. The calibration table bins the stated confidence
and gives the share of right estimates (<= 3 deg, right sign) in each bin and among those labelled
confident (the target: 1.0).

Run time (measured on the shared 2-core machine at load average ~10): the estimate alone 15 s for all
55 cases (`--no-missions`); with missions 540 s (a mission 4-26 s, the checker included; the 14
cases whose estimate is not confident stop in under a second); `--no-rotations` about a fifth.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.scan_corpus import (
    APARTMENT_TARGET,
    CAMERAS,
    MAX_ANGLE_DEG,
    calibration,
    cases,
    estimate_case,
    manifest_scans,
    up_error,
)
from perch_operator.bench import camera_count


def register(sub) -> None:
    """Add `perch bench scans` to the CLI."""
    p = sub.add_parser("scans", help="every real scan in its own frame and 4 rotations: up error and confidence, "
                                     "cameras, safety evidence, checker verdicts, observed share, calibration")
    p.add_argument("--only", action="append", default=[], metavar="TEXT",
                   help="only scans whose file name contains TEXT (repeatable)")
    p.add_argument("--no-rotations", action="store_true", help="each scan in its own frame only")
    p.add_argument("--manifest", action="append", default=[], metavar="PATH",
                   help="also every scan of this MANIFEST.tsv (the shared format: tab-separated columns 'file' "
                        "and 'up', files beside it; repeatable)")
    p.add_argument("--no-missions", action="store_true", help="the up estimate only (no graph, no missions)")
    p.add_argument("--cameras", type=camera_count, default=CAMERAS,
                   help=f"cameras per mission (default {CAMERAS}; 0: the node's default)")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    started = time.perf_counter()
    for manifest in args.manifest:  # a bad manifest is refused before any work, naming the row
        try:
            manifest_scans(manifest)
        except ValueError as error:
            print(f"perch bench scans: error: {error}", file=sys.stderr)
            return 2
    rows, missions = [], None
    runner = None if args.no_missions else _MissionRunner(args.cameras)
    try:
        for name, orientation, mesh, true_up, path, target in cases(args.only, not args.no_rotations, args.manifest):
            row = {"scan": name, "orientation": orientation, "faces": mesh.num_faces}
            row.update(estimate_case(mesh, true_up, path))
            if runner is not None:
                row.update(runner.run(mesh, true_up, path, target))
            rows.append(row)
            print(f"perch bench scans: {name} {orientation}: up {row['up_error_deg']:.1f} deg "
                  f"{'right' if row['right'] else 'WRONG'}, confidence {row['confidence']:.2f}"
                  + (f", {row['cameras']} camera(s) in {row['mission_seconds']:.1f} s" if runner else ""),
                  file=sys.stderr, flush=True)
    finally:
        if runner is not None:
            missions = runner.notes
            runner.stop()
    wrong_confident = [f"{r['scan']} {r['orientation']}" for r in rows if r["confident"] and not r["right"]]
    summary = {"cases": len(rows), "right": sum(r["right"] for r in rows),
               "not_confident": sum(not r["confident"] for r in rows),
               "confident_but_wrong": wrong_confident,
               "right_or_honest": not wrong_confident,
               "max_up_error_deg_when_confident": max((r["up_error_deg"] for r in rows if r["confident"]), default=None)}
    if runner is not None:
        summary.update({
            "missions_stopped": sum(not r["mission_success"] for r in rows),
            "cameras_placed": sum(r["cameras"] for r in rows),
            "checker_failures": None if any(r["checker"] is None for r in rows)
            else sum(not v["safe"] for r in rows for v in r["checker"]),
            "internal_errors": sum("internal error" in r["mission_message"].lower() for r in rows)})
    return emit({"cases": rows, "calibration": calibration(rows), "summary": summary,
                 "notes": missions or [], "targets": {"up_error_deg": MAX_ANGLE_DEG, "confident_share_right": 1.0},
                 "seconds": round(time.perf_counter() - started, 1), "peak_rss_mb": peak_rss_mb(),
                 "load_average_1min": round(os.getloadavg()[0], 2)})


class _MissionRunner:
    """One graph in this process (started once) and a mission per case, with the proposals' evidence."""

    def __init__(self, cameras: int):
        import rclpy

        from perch_common.launch import use_perch_dds
        from perch_interfaces.msg import Proposal
        from perch_operator.cli.runner import choose_domain, client_context, graph_ros_args, start_own_graph
        from perch_operator.coordinator.node import LATCHED

        self.cameras = cameras
        self.notes: list[str] = []
        use_perch_dds()
        domain = choose_domain()
        self._context = client_context(graph_ros_args(None, [], None), domain)
        self._context.__enter__()
        self.node = rclpy.create_node("perch_bench_scans")
        self.proposals: dict[int, Proposal] = {}
        self.node.create_subscription(Proposal, "perch/proposals", lambda m: self.proposals.__setitem__(m.id, m),
                                      LATCHED)
        self.graph = start_own_graph(self.node, "one-process", domain)
        self.checker = _project_checker(self.notes)

    def run(self, mesh, true_up: np.ndarray, path, target) -> dict:
        from perch_common.ros.conversions import mesh_to_msg
        from perch_common.ros.static_transforms import alignment_from_msg
        from perch_common.up_axis import file_convention
        from perch_interfaces import msg as pm
        from perch_interfaces.action import PlanPerches
        from perch_operator.api.client import run_mission
        from perch_operator.cli.runner import spin_for

        goal = PlanPerches.Goal(num_cameras=self.cameras, auto_accept=True, seed=-1, up_axis="auto",
                                up_convention=file_convention(path), mesh=mesh_to_msg(mesh))
        if target is not None:  # the apartment's own target footprint, extruded 1.2 m along the true up
            goal.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT, footprint=mesh_to_msg(target),
                                          height=float(APARTMENT_TARGET[2]))
        else:
            goal.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_DEFAULT)
        first_id = max(self.proposals, default=0)
        start = time.perf_counter()
        try:
            result = run_mission(self.node, goal, timeout=900)
        except Exception as exc:  # noqa: BLE001 - a failing case is a row of the table, not the end of it
            return {"mission_success": False, "mission_message": f"internal error: {type(exc).__name__}: {exc}",
                    "cameras": 0, "perches": [], "checker": [], "mission_seconds": round(time.perf_counter() - start, 2)}
        seconds = time.perf_counter() - start
        spin_for(self.node, 0.3)   # the last proposals' messages
        accepted = sorted((p for i, p in self.proposals.items() if i > first_id and p.status == p.STATUS_ACCEPTED),
                          key=lambda p: p.placement.drone_index)
        row = {"mission_success": bool(result.success), "mission_message": result.message[:400],
               "cameras": len(result.placements), "mission_seconds": round(seconds, 2)}
        if result.success:
            used = alignment_from_msg(result.alignment).up
            row["planned_up_error_deg"], row["planned_sign_right"] = up_error(used, true_up)
        row["perches"] = [_perch_row(p) for p in accepted]
        row["checker"] = self.checker(mesh, true_up, row["perches"]) if self.checker else None
        if row["checker"] is not None:   # Perch claims every accepted perch safe: an unsafe verdict disagrees
            row["checker_unsafe"] = sum(not v["safe"] for v in row["checker"])
        return row

    def stop(self) -> None:
        self.graph.stop()
        self.node.destroy_node()
        self._context.__exit__(None, None, None)


def _perch_row(proposal) -> dict:
    """A perch's position (input frame) and every field of its safety evidence, as the proposal carries them."""
    evidence = proposal.evidence
    fields = {name: round(float(getattr(evidence, name)), 3) for name in evidence.get_fields_and_field_types()
              if isinstance(getattr(evidence, name), (int, float))}
    from scipy.spatial.transform import Rotation

    pose = proposal.placement.drone_pose
    q = pose.orientation
    normal = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()[:, 2]  # drone z: the surface normal
    return {"proposal_id": proposal.id, "drone": proposal.placement.drone_index,
            "position": [pose.position.x, pose.position.y, pose.position.z], "normal": normal.round(5).tolist(),
            "evidence": fields,
            # Perch's own observed share: the smaller of its approach prism's and fall corridor's (None
            # when the evidence has no observed-space fields)
            "observed_share": min(observed) if (observed := [v for k, v in fields.items() if k.endswith("_observed")])
            else None}


def _project_checker(notes: list[str]):
    """The project's perch checker (perch_filtering.perch_check) on the placed perches with the TRUE up,
    or None (with a note) when the installed packages lack it."""
    try:
        from perch_filtering.perch_check import check_perches
    except ImportError as exc:
        notes.append(f"checker: perch_filtering.perch_check is not importable ({exc}); the checker column is null")
        return None

    def check(mesh, true_up, perches: list[dict]) -> list[dict]:
        positions = np.array([p["position"] for p in perches], np.float64).reshape(-1, 3)
        normals = np.array([p["normal"] for p in perches], np.float64).reshape(-1, 3)
        return [{"safe": v.safe, "reasons": v.reasons, "kind": v.kind,
                 "observed_share": round(float(v.observed_share), 3)}
                for v in check_perches(mesh, positions, normals, true_up)]
    return check
