"""`perch bench soak`: many missions on one launched graph, as a dispatcher beside it would see them.

Each mission is a real `perch plan --no-launch` client process. Mixed in, chosen by a seeded
random generator: clients killed (SIGKILL) or interrupted (SIGINT, which cancels) mid-mission,
goals the coordinator must refuse with a clear reason, bad service requests between missions, and
one node killed and started again half-way. Every completed mission must have complete outputs
equal to the first one of its scene; every failed one a FAILED reason and no outputs; node RSS is
sampled at the start, after the 10th and after the last mission.

    perch bench soak --missions 50 --json
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

CAMERAS = 2
SCENE_SEEDS = (1, 3)          # generated rooms: each a few seconds per mission on two cores
KINDS = {"complete": 0.65, "kill": 0.12, "cancel": 0.12, "bad_goal": 0.11}
RESPAWNED_NODE = "perch_segmentation"
OUTPUTS = ("waypoints.yaml", "run.rrd", "report.html")


@dataclass
class SoakReport:
    """What the soak saw; `problems` lists every violated expectation (empty: the soak passed)."""

    missions: int
    kinds: dict[str, int] = field(default_factory=dict)
    completed: int = 0
    failed_with_reason: int = 0
    refused_retries: int = 0
    bad_requests: int = 0
    free_after_kill_s: list[float] = field(default_factory=list)
    mission_s: list[float] = field(default_factory=list)
    rss_mb: dict[str, dict[str, float]] = field(default_factory=dict)
    respawn: str = ""
    problems: list[str] = field(default_factory=list)

    def rss_growth_after_10th(self) -> dict[str, float]:
        """Per node: relative RSS change from after the 10th mission (10 after its respawn) to the end."""
        growth = {}
        for name, v in self.rss_mb.items():
            base = v.get("10_after_respawn", v.get("after_10"))
            if base and "end" in v:
                growth[name] = round((v["end"] - base) / base, 4)
        return growth

    def summary(self) -> dict:
        """A JSON-ready summary."""
        import statistics

        return {"missions": self.missions, "kinds": self.kinds, "completed": self.completed,
                "failed_with_reason": self.failed_with_reason, "refused_then_retried": self.refused_retries,
                "bad_requests_refused": self.bad_requests,
                "free_after_client_kill_s": [round(s, 1) for s in self.free_after_kill_s],
                "mission_wall_s_median": round(statistics.median(self.mission_s), 2) if self.mission_s else None,
                "respawn": self.respawn, "rss_mb": self.rss_mb,
                "rss_growth_after_10th": self.rss_growth_after_10th(), "problems": self.problems}


def plan_command(out: Path, scene: int, extra: tuple[str, ...] = ()) -> list[str]:
    """The client a dispatcher would run: `perch plan --no-launch` on a generated room."""
    return [sys.executable, "-m", "perch_common.cli", "plan", "--scene", str(scene), "--kind", "room",
            "--cameras", str(CAMERAS), "--auto-accept", "--no-launch", "--overwrite", "-o", str(out), *extra]


class Soak:
    """Runs the missions against `graph` (GraphProcesses) with the client node `node`."""

    def __init__(self, graph, node, work: Path, seed: int = 0, respawn=None, log=sys.stderr):
        self.graph = graph
        self.node = node
        self.work = Path(work)
        self.rng = random.Random(seed)
        self.respawn = respawn       # callable(name) that brings a killed node back; None: restart it here
        self.log = log
        self.reference: dict[int, list[dict]] = {}

    def say(self, text: str) -> None:
        """One progress line on the log stream."""
        self.log.write(f"[soak] {text}\n")
        self.log.flush()

    def run(self, missions: int, kinds: list[str] | None = None) -> SoakReport:
        """Run `missions` missions (of the given `kinds`, else a seeded random mix) and return what was seen."""
        report = SoakReport(missions)
        self._sample_rss(report, "start")
        for i in range(missions):
            if kinds is not None:
                kind = kinds[i % len(kinds)]
            else:
                kind = "complete" if i == 0 else self.rng.choices(list(KINDS), weights=list(KINDS.values()))[0]
            report.kinds[kind] = report.kinds.get(kind, 0) + 1
            if i == missions // 2:
                self._kill_and_respawn(report)
            self._mission(i, kind, report)
            if i % 3 == 2:
                self._bad_request(report)
            if i + 1 == 10:
                self._sample_rss(report, "after_10")
            if i + 1 == missions // 2 + 10 and i + 1 < missions:
                self._sample_rss(report, "10_after_respawn", [RESPAWNED_NODE])
        self._sample_rss(report, "end")
        dead = [n for n, ok in self.graph.alive().items() if not ok]
        if dead:
            report.problems.append(f"nodes dead at the end: {dead}")
        for name, growth in report.rss_growth_after_10th().items():
            if missions >= 20 and growth >= 0.10:
                report.problems.append(f"{name}: RSS grew {100 * growth:.1f} % after the 10th mission")
        return report

    # --- missions ---------------------------------------------------------------------------------

    def _mission(self, index: int, kind: str, report: SoakReport) -> None:
        out = self.work / f"mission_{index:03d}"
        scene = SCENE_SEEDS[index % len(SCENE_SEEDS)]
        extra = ("--target", "box:nan,1,1,1,1,1") if kind == "bad_goal" else ()
        started = time.monotonic()
        code, output = self._run_client(out, scene, extra, kind, report)
        report.mission_s.append(time.monotonic() - started)
        problem = self._check(out, scene, kind, code, output, report)
        if problem:
            report.problems.append(f"mission {index} ({kind}): {problem}")
            self.say(f"mission {index} ({kind}): PROBLEM {problem}")
        else:
            self.say(f"mission {index} ({kind}): ok in {report.mission_s[-1]:.1f} s")
        if kind == "kill":
            report.free_after_kill_s.append(self._wait_free())

    def _run_client(self, out: Path, scene: int, extra, kind: str, report: SoakReport) -> tuple[int, str]:
        """Start the client (again while the coordinator refuses it); interrupt or kill it when asked."""
        log_path = self.work / f"{out.name}.log"
        for _ in range(60):
            with open(log_path, "w") as stream:
                proc = subprocess.Popen(plan_command(out, scene, extra), stdout=stream, stderr=subprocess.STDOUT,
                                        env=dict(os.environ))
            if kind in ("kill", "cancel"):
                self._interrupt(proc, log_path, signal.SIGKILL if kind == "kill" else signal.SIGINT)
            try:
                code = proc.wait(600)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = proc.wait()
            output = log_path.read_text()
            if code == 1 and "rejected the goal" in output:
                report.refused_retries += 1
                if out.exists():
                    return code, output + "\n(a refused goal created the output folder)"
                time.sleep(1.0)
                continue
            return code, output
        return code, output

    def _interrupt(self, proc: subprocess.Popen, log_path: Path, sig: int) -> None:
        """Once the mission runs (the goal is sent), wait a random moment and send `sig`."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if " s] " in log_path.read_text():   # the first progress line: the mission runs
                break
            time.sleep(0.1)
        time.sleep(self.rng.uniform(0.2, 3.0))
        if proc.poll() is None:
            proc.send_signal(sig)

    def _check(self, out: Path, scene: int, kind: str, code: int, output: str, report: SoakReport) -> str:
        """'' when the outputs are what this kind of mission must leave, else what is wrong."""
        present = [n for n in OUTPUTS if (out / n).exists()]
        failed = out / "FAILED"
        if code == 0:
            if kind in ("bad_goal",):
                return "a goal with a NaN target succeeded"
            if failed.exists() or len(present) != len(OUTPUTS):
                return f"exit 0 but outputs {present}, FAILED {failed.exists()}"
            waypoints = yaml.safe_load((out / "waypoints.yaml").read_text())["waypoints"]
            perches = [{k: v for k, v in w.items() if k != "proposal_id"} for w in waypoints]
            expected = self.reference.setdefault(scene, perches)
            if len(waypoints) != CAMERAS or perches != expected:
                return f"waypoints differ from the scene's first mission: {waypoints}"
            report.completed += 1
            return ""
        if kind == "kill" and len(present) == len(OUTPUTS) and not failed.exists():
            report.completed += 1   # killed after its outputs were moved into place: they are complete
            return ""
        if present:
            return f"failed (exit {code}) but left outputs {present}"
        if kind == "kill":
            return "" if code == -signal.SIGKILL else f"killed client exited {code}"
        if not failed.exists():
            return f"failed (exit {code}) without a FAILED reason; output: {output[-300:]}"
        reason = failed.read_text()
        wanted = {"cancel": "interrupt", "bad_goal": "must be a finite number"}.get(kind, "")
        if wanted not in reason.lower():
            return f"FAILED does not say {wanted!r}: {reason[:200]}"
        report.failed_with_reason += 1
        return ""

    def _wait_free(self, within: float = 30.0) -> float:
        """Seconds until the coordinator accepts goals again (it aborts a vanished client's mission)."""
        from rclpy.action import ActionClient

        from perch_interfaces.action import PlanPerches
        from perch_operator.client import ACTION
        from perch_operator.runner import spin_for

        started = time.monotonic()
        client = ActionClient(self.node, PlanPerches, ACTION)
        try:
            client.wait_for_server(timeout_sec=10)
            while time.monotonic() - started < within:
                # A goal without input is accepted only by a free coordinator and then fails at once.
                sent = client.send_goal_async(PlanPerches.Goal())
                while not sent.done():
                    spin_for(self.node, 0.05)
                handle = sent.result()
                if handle.accepted:
                    result = handle.get_result_async()
                    while not result.done():
                        spin_for(self.node, 0.05)
                    return time.monotonic() - started
                time.sleep(0.5)
        finally:
            client.destroy()
        return float("inf")

    # --- bad requests, node death -------------------------------------------------------------------

    def _bad_request(self, report: SoakReport) -> None:
        from perch_common.ros.testing import call_service

        name, srv_type, request, wanted = self.rng.choice(bad_requests())
        try:
            reply = call_service(self.node, srv_type, name, request, timeout=60, wait=10)
        except TimeoutError as exc:
            report.problems.append(f"bad request to {name}: {exc}")
            return
        if reply.success or wanted not in reply.message:
            report.problems.append(f"bad request to {name}: success={reply.success}, {reply.message!r} "
                                   f"(wanted {wanted!r})")
        else:
            report.bad_requests += 1

    def _kill_and_respawn(self, report: SoakReport) -> None:
        from perch_operator.runner import NODE_SERVICES

        proc = self.graph.processes[RESPAWNED_NODE]
        proc.kill()
        proc.wait()
        started = time.monotonic()
        if self.respawn is not None:
            self.respawn(RESPAWNED_NODE)
            how = "the launcher's respawn"
        else:
            time.sleep(4.0)   # let the graph forget the dead process (lease 3 s)
            self.graph.start_node(RESPAWNED_NODE)
            how = "restarted by the soak (GraphProcesses.start_node)"
        missing = self.graph.wait_for_services(
            self.node, [self.node.resolve_service_name(NODE_SERVICES[RESPAWNED_NODE][0])], 120)
        if missing:
            report.problems.append(f"{RESPAWNED_NODE} did not come back: {missing}")
        report.respawn = f"{RESPAWNED_NODE} SIGKILLed, back in {time.monotonic() - started:.1f} s ({how})"
        self.say(report.respawn)

    def _sample_rss(self, report: SoakReport, when: str, only: list[str] | None = None) -> None:
        import psutil

        for name, proc in self.graph.processes.items():
            if only is not None and name not in only:
                continue
            try:
                rss = psutil.Process(proc.pid).memory_info().rss / 2**20
            except psutil.NoSuchProcess:
                continue
            report.rss_mb.setdefault(name, {})[when] = round(rss, 1)


def bad_requests() -> list[tuple[str, type, object, str]]:
    """(service, type, request, expected words in the error reply): the issue's bad inputs."""
    import math

    from perch_common.ros.conversions import mesh_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_interfaces import msg as pm
    from perch_interfaces import srv

    mesh = generate_scene(1, "room").mesh
    far = mesh_to_msg(type(mesh)(mesh.vertices * 1e8, mesh.faces))
    good = mesh_to_msg(mesh)
    box = pm.OrientedBox()
    box.size.x = box.size.y = box.size.z = 1.0
    nan_box = pm.OrientedBox(size=box.size)
    nan_box.pose.position.x = math.nan
    zero_q = pm.OrientedBox(size=box.size)
    zero_q.pose.orientation.w = 0.0
    target = pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX, box=box)
    return [
        ("perch/crop", srv.Crop, srv.Crop.Request(mesh=good, keep_boxes=[nan_box]), "must be a finite number"),
        ("perch/crop", srv.Crop, srv.Crop.Request(mesh=good, keep_boxes=[zero_q]), "not a unit quaternion"),
        ("perch/segment", srv.Segment, srv.Segment.Request(mesh=far), "beyond 10 km"),
        ("perch/clean_mesh", srv.CleanMesh, srv.CleanMesh.Request(mesh=good, target_faces=1), "target_faces = 1"),
        ("perch/optimise", srv.Optimise, srv.Optimise.Request(
            mesh=good, target=target, drone=pm.DroneSpec(specified=True, radius=-1.0)), "drone.radius = -1"),
        ("perch/optimise", srv.Optimise, srv.Optimise.Request(
            mesh=good, target=target, camera=pm.CameraSpec(specified=True)), "camera.width = 0"),
    ]


def register(sub) -> None:
    """`perch bench soak`."""
    p = sub.add_parser("soak", help="missions with killed/cancelled clients, bad requests and a node respawn")
    p.add_argument("--missions", type=int, default=50)
    p.add_argument("--seed", type=int, default=0, help="seed of the random mix")
    p.add_argument("--work", type=Path, help="folder for the missions' outputs (default: a temporary one)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (always JSON on stdout)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    import rclpy

    from perch_common.bench import emit
    from perch_common.launch import GraphProcesses
    from perch_common.ros.testing import use_isolated_ros_env
    from perch_operator.runner import NODE_SERVICES, client_context

    if "ROS_DOMAIN_ID" not in os.environ:
        use_isolated_ros_env()
    else:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        from perch_common.launch import use_fast_liveliness

        use_fast_liveliness()
    work = args.work or Path(tempfile.mkdtemp(prefix="perch_soak_"))
    work.mkdir(parents=True, exist_ok=True)
    with client_context(), GraphProcesses(None, list(NODE_SERVICES), log_dir=work / "logs") as graph:
        node = rclpy.create_node("perch_soak")
        missing = graph.wait_for_services(node, [node.resolve_service_name(s[0]) for s in NODE_SERVICES.values()], 180)
        if missing:
            raise RuntimeError(f"services missing: {missing}; logs in {work / 'logs'}")
        report = Soak(graph, node, work, args.seed).run(args.missions)
        summary = report.summary()
        summary["work"] = str(work)
        emit(summary)
    return 1 if report.problems else 0
