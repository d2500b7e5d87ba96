"""`perch bench soak`: many missions on one launched graph, as a dispatcher beside it would see them.

The graph is `perch launch` (a child process; it respawns a node that dies); each mission is a
real `perch plan --no-launch` client process. Mixed in, chosen by a seeded
random generator: clients killed (SIGKILL) or interrupted (SIGINT, which cancels) mid-mission,
goals the coordinator must refuse with a clear reason, bad service requests between missions, and
one node killed and started again half-way. Every completed mission must have complete outputs
equal to the first one of its scene; every failed one a FAILED reason and no outputs; node RSS is
sampled at the start, after the 10th and after the last mission.

    perch bench soak --missions 50 --json
"""

from __future__ import annotations

import contextlib
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

from perch_common.conventions import NODE_SERVICES
from perch_common.outputs import STAGING_MARK

CAMERAS = 2
SCENE_SEEDS = (1, 3)          # generated rooms: each a few seconds per mission on two cores
KINDS = {"complete": 0.65, "kill": 0.12, "cancel": 0.12, "bad_goal": 0.11}
RESPAWNED_NODE = "perch_segmentation"
OUTPUTS = ("waypoints.yaml", "run.rrd", "report.html")
# A killed or interrupted client gets its signal once its progress shows one of these stages (chosen at
# random) or a later one, so that it lands mid-mission even when a whole mission takes 2 s.
INTERRUPT_AT = ("crop", "segment", "filter", "optimise")
MISSION_STAGES = ("clean", "crop", "segment", "filter", "optimise", "confirm")   # as the client prints them
INTERRUPT_JITTER = 0.3   # s, at most, after that line
PER_MISSION = ("proposal_id", "mission_id")   # waypoint fields that differ between equal missions


@dataclass
class SoakReport:
    """What the soak saw; `problems` lists every violated expectation (empty: the soak passed)."""

    missions: int
    kinds: dict[str, int] = field(default_factory=dict)
    completed: int = 0
    failed_with_reason: int = 0
    cancelled_mid_mission: int = 0
    killed_mid_mission: int = 0
    finished_before_signal: int = 0
    refused_retries: int = 0
    bad_requests: int = 0
    free_after_kill_s: list[float] = field(default_factory=list)
    mission_s: list[float] = field(default_factory=list)
    rss_mb: dict[str, dict[str, float]] = field(default_factory=dict)
    operator_rss_mb: list[float] = field(default_factory=list)   # the coordinator's RSS after each mission
    operator_traced: dict = field(default_factory=dict)   # --tracemalloc: Python's share of it, 10th to last
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

    def operator_growth(self) -> float | None:
        """The coordinator's relative RSS change from after the 10th mission to after the last."""
        curve = self.operator_rss_mb
        return round((curve[-1] - curve[9]) / curve[9], 4) if len(curve) > 10 and curve[9] else None

    def summary(self) -> dict:
        """A JSON-ready summary."""
        import statistics

        return {"missions": self.missions, "kinds": self.kinds, "completed": self.completed,
                "failed_with_reason": self.failed_with_reason, "cancelled_mid_mission": self.cancelled_mid_mission,
                "killed_mid_mission": self.killed_mid_mission, "finished_before_signal": self.finished_before_signal,
                "refused_then_retried": self.refused_retries,
                "bad_requests_refused": self.bad_requests,
                "free_after_client_kill_s": [round(s, 1) for s in self.free_after_kill_s],
                "mission_wall_s_median": round(statistics.median(self.mission_s), 2) if self.mission_s else None,
                "respawn": self.respawn, "rss_mb": self.rss_mb, "operator_rss_mb": self.operator_rss_mb,
                "operator_growth_10_to_end": self.operator_growth(),
                "rss_growth_after_10th": self.rss_growth_after_10th(), "operator_traced": self.operator_traced,
                "problems": self.problems}


def plan_command(out: Path, scene: int, extra: tuple[str, ...] = ()) -> list[str]:
    """The client a dispatcher would run: `perch plan --no-launch` on a generated room."""
    return [sys.executable, "-m", "perch_common.cli", "plan", "--scene", str(scene), "--kind", "room",
            "--cameras", str(CAMERAS), "--auto-accept", "--no-launch", "--overwrite", "-o", str(out),
            "--up", "+z", *extra]   # the generator's rooms are +z up: the soak is not about estimating it


class LaunchedGraph:
    """`perch launch` as a child process (every node its own process, respawned when it dies)."""

    def __init__(self, work: Path, env: dict | None = None, without: list[str] = ()):
        from perch_common.launch import GraphProcesses

        self.log_path = Path(work) / "launch.log"
        self.without = list(without)
        self.extra: dict[str, subprocess.Popen] = {}   # nodes the soak runs itself (heaptrack)
        nodes = ["--nodes", ",".join(n for n in GraphProcesses().nodes if n not in without)] if without else []
        with open(self.log_path, "w") as stream:
            self.proc = subprocess.Popen([sys.executable, "-m", "perch_common.cli", "launch", "--log-dir",
                                          str(Path(work) / "logs"), *nodes], stdout=stream,
                                         stderr=subprocess.STDOUT, env=dict(os.environ if env is None else env))

    def pids(self) -> dict[str, int]:
        """Node name -> process id of the launcher's node processes now running."""
        import psutil

        found = {}
        for child in psutil.Process(self.proc.pid).children():
            try:
                cmd = child.cmdline()
            except psutil.NoSuchProcess:
                continue
            if "-m" in cmd and child.status() != psutil.STATUS_ZOMBIE:
                found[cmd[cmd.index("-m") + 1].split(".")[0]] = child.pid
        found.update({name: proc.pid for name, proc in self.extra.items() if proc.poll() is None})
        return found

    def alive(self) -> dict[str, bool]:
        """The launcher and each node it runs: still running?"""
        return {"perch launch": self.proc.poll() is None, **{name: True for name in self.pids()}}

    def stop(self) -> None:
        """Ctrl-C to the launcher (it stops its nodes)."""
        from perch_common.processes import stop_process

        stop_process(self.proc, 30)


class Soak:
    """Runs the missions against a LaunchedGraph with the client node `node`."""

    def __init__(self, graph: LaunchedGraph, node, work: Path, seed: int = 0, log=None, traces: Path | None = None,
                 heaptrack: "CoordinatorHeaptrack | None" = None, smaps: Path | None = None,
                 interrupt_at: tuple[str, ...] = INTERRUPT_AT):
        self.graph = graph
        self.interrupt_at = interrupt_at   # the stages a killed or interrupted client waits for
        self.traces = traces   # the graph's record_traced folder (--tracemalloc), else None
        self.heaptrack = heaptrack
        self.smaps = smaps   # a folder for the coordinator's /proc/PID/smaps after each mission, else None
        self._traced_after_10: Path | None = None
        self.node = node
        self.work = Path(work)
        self.rng = random.Random(seed)
        self.log = log
        self.reference: dict[int, list[dict]] = {}

    def say(self, text: str) -> None:
        """One progress line on the log stream."""
        stream = self.log or sys.stderr   # looked up per line: a test harness swaps sys.stderr
        stream.write(f"[soak] {text}\n")
        stream.flush()

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
            self._operator_rss(report)
            if self.heaptrack is not None and i + 1 == self.heaptrack.after:
                self.heaptrack.mark_now()
            if i + 1 == 10:
                self._sample_rss(report, "after_10")
                self._traced_after_10 = self._operator_traced()
            if i + 1 == missions // 2 + 10 and i + 1 < missions:
                self._sample_rss(report, "10_after_respawn", [RESPAWNED_NODE])
        self._sample_rss(report, "end")
        self._compare_traced(report)
        running = self.graph.pids()
        missing = [n for n in NODE_SERVICES if n not in running]
        if missing or not self.graph.alive()["perch launch"]:
            report.problems.append(f"not running at the end: {missing or ['perch launch']}")
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
        if not problem and kind != "kill":
            # The client removed its own staging folder and, starting, those of killed clients before it.
            left = sorted(p.name for p in self.work.glob(f".*{STAGING_MARK}*"))
            problem = f"staging folders left behind: {left}" if left else ""
        if problem:
            report.problems.append(f"mission {index} ({kind}): {problem}")
            self.say(f"mission {index} ({kind}): PROBLEM {problem}")
            self.say(self.log_tails(problem))
        else:
            self.say(f"mission {index} ({kind}): ok in {report.mission_s[-1]:.1f} s")
        if kind == "kill":
            report.free_after_kill_s.append(self._wait_free())

    def log_tails(self, problem: str, lines: int = 40) -> str:
        """The end of the coordinator's log and of the log of each node the problem names (its stage's), so
        a failed soak says what the graph saw (a test's folder is gone when CI prints its failure)."""
        nodes = ["perch_operator"] + [node for node, services in NODE_SERVICES.items()
                                      if node != "perch_operator" and (node in problem or any(
                                          f"({self.node.resolve_service_name(s)})" in problem for s in services))]
        parts = []
        for node in nodes:
            path = self.graph.log_path.parent / "logs" / f"{node}.log"
            text = path.read_text(errors="replace").splitlines()[-lines:] if path.is_file() else ["(no log)"]
            parts.append(f"--- last lines of {path}:\n" + "\n".join(text))
        return "\n".join(parts)

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
        """Once the mission reaches a stage chosen at random, wait a random moment and send `sig`.

        The client prints a line when a stage starts: the first feedback message of the stage it gets,
        "running <stage>" as a rule, but once in 11 local runs "segment: prepare" (the stage's first
        message never reached that client), so any line of the stage, or of a later one, counts."""
        stage = self.rng.choice(self.interrupt_at)
        delay = self.rng.uniform(0.0, INTERRUPT_JITTER)
        reached = [f"] {later}: " for later in MISSION_STAGES[MISSION_STAGES.index(stage):]]
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            text = log_path.read_text()
            if any(line in text for line in reached):
                break
            time.sleep(0.02)
        time.sleep(delay)
        if proc.poll() is None:
            proc.send_signal(sig)

    def _check(self, out: Path, scene: int, kind: str, code: int, output: str, report: SoakReport) -> str:
        """'' when the outputs are what this kind of mission must leave, else what is wrong."""
        present = [n for n in OUTPUTS if (out / n).exists()]
        failed = out / "FAILED"
        # A client killed or interrupted after its outputs were moved into place finished its mission:
        # the outputs must then be complete and correct, like an ordinary mission's.
        finished_first = kind in ("kill", "cancel") and len(present) == len(OUTPUTS) and not failed.exists()
        if code == 0 or finished_first:
            if kind in ("bad_goal",):
                return "a goal with a NaN target succeeded"
            if failed.exists() or len(present) != len(OUTPUTS):
                return f"exit 0 but outputs {present}, FAILED {failed.exists()}"
            waypoints = yaml.safe_load((out / "waypoints.yaml").read_text())["waypoints"]
            perches = [{k: v for k, v in w.items() if k not in PER_MISSION} for w in waypoints]
            expected = self.reference.setdefault(scene, perches)
            if len(waypoints) != CAMERAS or perches != expected:
                return f"waypoints differ from the scene's first mission: {waypoints}"
            report.completed += 1
            report.finished_before_signal += finished_first
            return ""
        if present:
            return f"failed (exit {code}) but left outputs {present}"
        if kind == "kill":
            if code != -signal.SIGKILL:
                return f"killed client exited {code}"
            report.killed_mid_mission += 1
            return ""
        if not failed.exists():
            return f"failed (exit {code}) without a FAILED reason; output: {output[-300:]}"
        reason = failed.read_text()
        if kind == "complete":
            return f"an ordinary mission failed: {reason.splitlines()[0]}"
        wanted = {"cancel": "interrupt", "bad_goal": "must be a finite number"}.get(kind, "")
        if wanted not in reason.lower():
            return f"FAILED does not say {wanted!r}: {reason[:200]}"
        report.failed_with_reason += 1
        report.cancelled_mid_mission += kind == "cancel"
        return ""

    def _wait_free(self, within: float = 30.0) -> float:
        """Seconds until the coordinator accepts goals again (it aborts a vanished client's mission)."""
        from rclpy.action import ActionClient

        from perch_interfaces.action import PlanPerches
        from perch_operator.api.client import ACTION
        from perch_operator.cli.runner import spin_for

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
        import psutil

        pid = self.graph.pids()[RESPAWNED_NODE]
        psutil.Process(pid).kill()
        started = time.monotonic()
        service = self.node.resolve_service_name(NODE_SERVICES[RESPAWNED_NODE][0])
        back, new_since = None, None
        while time.monotonic() - started < 120:
            now = self.graph.pids().get(RESPAWNED_NODE)
            if now is not None and now != pid:
                new_since = new_since or time.monotonic()
                # The dead process's service lingers for the DDS lease (3 s): wait past it.
                offered = service in {n for n, _ in self.node.get_service_names_and_types()}
                if offered and time.monotonic() - new_since > 4.0:
                    back = time.monotonic() - started
                    break
            time.sleep(0.2)
        if back is None:
            report.problems.append(f"{RESPAWNED_NODE} was not respawned within 120 s")
            return
        report.respawn = f"{RESPAWNED_NODE} SIGKILLed, respawned by perch launch and serving again in {back:.1f} s"
        self.say(report.respawn)

    def _operator_rss(self, report: SoakReport) -> None:
        import psutil

        pid = self.graph.pids().get("perch_operator")
        with contextlib.suppress(psutil.NoSuchProcess, TypeError):
            report.operator_rss_mb.append(round(psutil.Process(pid).memory_info().rss / 2**20, 1))
        if self.smaps is not None and pid is not None:
            with contextlib.suppress(OSError):
                self.smaps.mkdir(parents=True, exist_ok=True)
                text = Path(f"/proc/{pid}/smaps").read_text()
                (self.smaps / f"after_{len(report.mission_s):03d}.smaps").write_text(text)

    def _operator_traced(self) -> Path | None:
        """The coordinator's newest record of what Python holds (it writes one as it releases memory)."""
        pid = self.graph.pids().get("perch_operator")
        if self.traces is None or pid is None:
            return None
        return max(self.traces.glob(f"{pid}-*.json"), key=lambda p: int(p.stem.split("-")[1]), default=None)

    def _compare_traced(self, report: SoakReport) -> None:
        import json

        from perch_common.memory import traced_growth

        last = self._operator_traced()
        if self._traced_after_10 is None or last is None:
            if self.traces is not None:
                report.problems.append("--tracemalloc: the coordinator wrote no record after the 10th or the last mission")
            return
        report.operator_traced = traced_growth(json.loads(self._traced_after_10.read_text()),
                                               json.loads(last.read_text()))

    def _sample_rss(self, report: SoakReport, when: str, only: list[str] | None = None) -> None:
        import psutil

        for name, pid in self.graph.pids().items():
            if only is not None and name not in only:
                continue
            try:
                rss = psutil.Process(pid).memory_info().rss / 2**20
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


HEAPTRACK_LIB = Path("/usr/lib/heaptrack")   # Debian's heaptrack package
TRACED_NODE = "perch_operator"


class CoordinatorHeaptrack:
    """The coordinator run by the soak itself under heaptrack's preload library (the other nodes stay
    with `perch launch`). heaptrack writes its raw record as it goes; its length after `after` missions
    marks that moment, and `finish` SIGKILLs the coordinator (no shutdown frees anything) and
    interprets the record twice, cut at the mark and whole: `heaptrack_print -f end -d early -l` then
    lists by call stack what the coordinator allocated after mission `after` and still held at the end.
    (heaptrack -p attaches through gdb, which crashed the coordinator on this kind of host.)"""

    def __init__(self, folder: Path, after: int, work: Path):
        self.folder = Path(folder)
        self.after = after
        self.folder.mkdir(parents=True, exist_ok=True)
        self.raw = self.folder / "operator.raw"
        self.raw.unlink(missing_ok=True)   # heaptrack writes into an existing file without truncating it
        self.mark: int | None = None
        from perch_common.launch import GraphProcesses
        from perch_common.processes import child_environment

        graph = GraphProcesses(nodes=[TRACED_NODE], log_dir=Path(work) / "logs")
        env = dict(child_environment(graph.node_environment(TRACED_NODE)), DUMP_HEAPTRACK_OUTPUT=str(self.raw),
                   LD_PRELOAD=str(HEAPTRACK_LIB / "libheaptrack_preload.so"))
        (Path(work) / "logs").mkdir(parents=True, exist_ok=True)
        with open(Path(work) / "logs" / f"{TRACED_NODE}.log", "ab") as out:
            self.proc = subprocess.Popen(graph.command(TRACED_NODE), env=env, stdout=out, stderr=subprocess.STDOUT)

    def mark_now(self) -> None:
        """Remember how far the record has come (the moment the growth is measured from)."""
        self.mark = self.raw.stat().st_size

    def finish(self) -> dict[str, str]:
        """SIGKILL the traced coordinator and interpret its record; the interpreted files by name."""
        self.proc.kill()
        self.proc.wait()
        interpret = HEAPTRACK_LIB / "libexec" / "heaptrack_interpret"
        records = {}
        with open(self.raw, "rb") as raw:
            data = raw.read()
        cuts = {"end": len(data)}
        if self.mark is not None:
            cuts["early"] = data.rfind(b"\n", 0, self.mark) + 1   # whole lines only
        for name, cut in cuts.items():
            path = self.folder / f"operator.{name}.zst"
            with open(path, "wb") as out:
                interpreter = subprocess.Popen([str(interpret)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                compressor = subprocess.Popen(["zstd", "-q", "-c"], stdin=interpreter.stdout, stdout=out)
                interpreter.stdout.close()
                interpreter.communicate(data[:cut])
                compressor.wait()
            records[name] = str(path)
        return records


def register(sub) -> None:
    """`perch bench soak`."""
    from perch_common.cli_types import positive_int

    p = sub.add_parser("soak", help="missions with killed/cancelled clients, bad requests and a node respawn")
    p.add_argument("--missions", type=positive_int, default=50, help="missions to run (>= 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random mix")
    p.add_argument("--work", type=Path, help="folder for the missions' outputs (default: a temporary one)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (always JSON on stdout)")
    p.add_argument("--tracemalloc", action="store_true",
                   help="trace the graph's Python allocations (slower) and report what the coordinator's Python "
                        "objects grew by from the 10th mission to the last, by source line")
    p.add_argument("--heaptrack", type=Path, metavar="DIR",
                   help="run the coordinator under heaptrack (slower) and SIGKILL it after the last mission: "
                        "`heaptrack_print -f DIR/operator.end.zst -d DIR/operator.early.zst -l` lists what it "
                        "allocated after --heaptrack-after missions and still held; its RSS includes heaptrack's own")
    p.add_argument("--heaptrack-after", type=positive_int, default=10,
                   help="--heaptrack: the mission (>= 1) after which the growth is measured")
    p.add_argument("--smaps", type=Path, metavar="DIR",
                   help="keep the coordinator's /proc/PID/smaps after each mission in DIR (which mappings grow)")
    register_faults(p)
    p.set_defaults(func=_run)


def launched(work: Path, node, timeout: float = 180.0, env: dict | None = None, traced: bool = False) -> LaunchedGraph:
    """Start `perch launch` (in `env`, default this process's) and wait until every stage service is
    offered (`traced`: every node but the coordinator, which the soak starts under heaptrack)."""
    graph = LaunchedGraph(work, env, without=[TRACED_NODE] if traced else [])
    try:
        wait_offered(node, graph, timeout)
    except BaseException:   # Ctrl-C while the graph starts, or it failed: it must not outlive the soak
        graph.stop()
        raise
    return graph


def wait_offered(node, graph: LaunchedGraph, timeout: float) -> None:
    """Wait until the graph's nodes offer their services (RuntimeError when they do not in time)."""
    wanted = [node.resolve_service_name(s[0]) for n, s in NODE_SERVICES.items() if n not in graph.without]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if set(wanted) <= {n for n, _ in node.get_service_names_and_types()}:
            return
        if graph.proc.poll() is not None:
            break
        time.sleep(0.5)
    raise RuntimeError(f"perch launch did not offer {wanted} within {timeout:.0f} s; see {graph.log_path}")


def _run(args) -> int:
    import rclpy

    from perch_common.bench import emit
    from perch_common.ros.testing import use_isolated_ros_env
    from perch_operator.cli.runner import client_context

    if "ROS_DOMAIN_ID" not in os.environ:
        use_isolated_ros_env()
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started in the background by a shell, this process ignores SIGINT and its clients would
        # inherit that: the soak's interrupts must reach them as a Ctrl-C does.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    work = args.work or Path(tempfile.mkdtemp(prefix="perch_soak_"))
    work.mkdir(parents=True, exist_ok=True)
    with client_context():
        node = rclpy.create_node("perch_soak")
        if args.faults:
            faults = FaultSoak(work, node, args.seed)
            try:
                report = faults.run(args.faults)
            finally:
                faults.stop()
            orphans, dead_shm = left_behind()
            report.problems += leftover_problems(orphans, dead_shm)
            summary = report.summary()
            summary.update(orphans_after=len(orphans), dead_shm_files_after=len(dead_shm))
            summary["work"] = str(work)
            emit(summary)
            return 1 if report.problems else 0
        traces = work / "tracemalloc" if args.tracemalloc else None
        env = None
        if traces is not None:
            from perch_common.memory import TRACE_DIR_ENV

            traces.mkdir(exist_ok=True)
            env = dict(os.environ, PYTHONTRACEMALLOC="1", **{TRACE_DIR_ENV: str(traces)})
        graph = launched(work, node, env=env, traced=bool(args.heaptrack))
        heaptrack = None
        try:
            if args.heaptrack:
                heaptrack = CoordinatorHeaptrack(args.heaptrack, args.heaptrack_after, work)
                graph.extra[TRACED_NODE] = heaptrack.proc
                wait_offered(node, graph, 60.0)
            report = Soak(graph, node, work, args.seed, traces=traces, heaptrack=heaptrack,
                          smaps=args.smaps).run(args.missions)
        finally:
            records = heaptrack.finish() if heaptrack is not None else None
            graph.stop()
        summary = report.summary()
        summary["work"] = str(work)
        if records:
            summary["heaptrack"] = records
        emit(summary)
    return 1 if report.problems else 0


# --- faults: stage nodes, the coordinator and the launcher killed mid-mission -----------------------

# Node -> the stage it serves in a mission. A stage node is frozen (SIGSTOP) as soon as the mission
# reports that its stage is running (the call goes out right after; on the apartment each stage
# works for far longer than the report takes to arrive), so no reply slips out before it is
# SIGKILLed a random moment later. The coordinator is frozen alike: unfrozen, it finished a mission
# whose last stage ended within the kill's delay ("killed during optimise", result: success).
# Freezing it earlier would outlast the DDS lease on a slow machine:
# the node would leave the graph before its call, which the respawned node then serves.
FAULT_TARGETS: dict[str, str] = {
    "perch_reconstruction": "clean",
    "perch_segmentation": "segment",
    "perch_filtering": "filter",
    "perch_placement": "optimise",
    "perch_operator": "",      # the coordinator itself: killed while any stage runs
    "perch launch": "",        # the launcher: its nodes die with it, the graph is started again
}
FAULT_STAGES = ("clean", "crop", "segment", "filter", "optimise")
KILL_JITTER = 0.5     # s, at most, after the stage starts
CLEAR_END_S = 15.0    # every mission with a kill must end this soon after it, with the reason


@dataclass
class FaultReport:
    """What the fault soak saw; `problems` lists every violated expectation (empty: it passed)."""

    kills: dict[str, int] = field(default_factory=dict)
    end_s: list[float] = field(default_factory=list)      # kill -> the mission's clear end
    reasons: list[str] = field(default_factory=list)
    next_ok: int = 0
    missions: int = 0
    problems: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """A JSON-ready summary."""
        import statistics

        return {"missions": self.missions, "kills": self.kills,
                "end_s_max": round(max(self.end_s), 2) if self.end_s else None,
                "end_s_median": round(statistics.median(self.end_s), 2) if self.end_s else None,
                "end_s": [round(s, 2) for s in self.end_s], "next_mission_ok": self.next_ok,
                "reasons": self.reasons, "problems": self.problems}


def fault_goal(scene: int = 7):
    """An auto-accepted mission on a generated apartment: each stage takes long enough (~0.5-2 s) for
    the node frozen when the stage before it starts to be certainly frozen before its own call."""
    from perch_common.scene_generator import generate_scene
    from perch_operator.api.client import scene_goal

    return scene_goal(generate_scene(scene, "apartment"), CAMERAS, seed=1, up_axis="+z")


class FaultSoak:
    """Missions (run_mission in this process) with one node of a LaunchedGraph killed mid-mission each,
    then an ordinary mission that must succeed on the graph as `perch launch` brought it back."""

    def __init__(self, work: Path, node, seed: int = 0, log=None, graph: LaunchedGraph | None = None):
        self.work = Path(work)
        self.node = node
        self.rng = random.Random(seed)
        self.log = log
        self.graph = graph or launched(self.work, node)
        self.goal = fault_goal()

    def say(self, text: str) -> None:
        """One progress line on the log stream."""
        stream = self.log or sys.stderr
        stream.write(f"[faults] {text}\n")
        stream.flush()

    def run(self, kills: int, targets: list[str] | None = None) -> FaultReport:
        """`kills` missions each with a kill (targets in a seeded random order), each followed by an ordinary one."""
        report = FaultReport()
        pool = list(targets or FAULT_TARGETS)
        order: list[str] = []
        while len(order) < kills:
            order += self.rng.sample(pool, len(pool))
        for target in order[:kills]:
            report.kills[target] = report.kills.get(target, 0) + 1
            self._killed_mission(target, report)
            self._next_mission(report)
        return report

    def stop(self) -> None:
        """Stop the graph (Ctrl-C to the launcher)."""
        self.graph.stop()

    def _killed_mission(self, target: str, report: FaultReport) -> None:
        import threading

        from perch_operator.api.client import run_mission

        report.missions += 1
        pids = self.graph.pids()
        stage = FAULT_TARGETS[target] or self.rng.choice(FAULT_STAGES)
        freeze = target != "perch launch"   # the launcher's nodes die with it, not when it stops
        pid = self.graph.proc.pid if target == "perch launch" else pids[target]
        delay = self.rng.uniform(0.0, KILL_JITTER)
        killed_at: list[float] = []

        def kill() -> None:
            os.kill(pid, signal.SIGKILL)
            killed_at.append(time.monotonic())

        def on_feedback(feedback) -> None:
            if feedback.stage == stage and not hasattr(kill, "timer"):
                if freeze:
                    os.kill(pid, signal.SIGSTOP)
                kill.timer = threading.Timer(delay, kill)
                kill.timer.start()

        try:
            result = run_mission(self.node, self.goal, timeout=120, on_feedback=on_feedback)
        except Exception as exc:  # noqa: BLE001 - any client failure is this mission's problem, said so
            result = None
            report.problems.append(f"kill {target} at {stage}: the client failed: {type(exc).__name__}: {exc}")
        ended = time.monotonic()
        if hasattr(kill, "timer"):
            kill.timer.join()
        if not killed_at:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)   # never left frozen
            report.problems.append(f"kill {target}: the mission ended before the kill (at {stage})")
            return
        seconds = ended - killed_at[0]
        report.end_s.append(seconds)
        reason = result.message if result is not None else ""
        report.reasons.append(f"{target} at {stage}: {reason}")
        # the launcher's nodes die with it: the reason names whichever the mission noticed first
        named = list(NODE_SERVICES) if target == "perch launch" else [target]
        self.say(f"killed {target} during {stage}: mission ended {seconds:.1f} s later: {reason}")
        if result is not None and (result.success or not any(n in reason for n in named)):
            report.problems.append(f"kill {target} at {stage}: result {result.success} {reason!r} "
                                   f"does not name {named}")
        if seconds > CLEAR_END_S:
            report.problems.append(f"kill {target} at {stage}: the mission ended {seconds:.1f} s after it")
        if target == "perch launch":
            self._relaunch(pids, report)

    def _relaunch(self, pids: dict[str, int], report: FaultReport) -> None:
        import psutil

        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(psutil.pid_exists(p) and psutil.Process(p).status()
                                                   != psutil.STATUS_ZOMBIE for p in pids.values()):
            time.sleep(0.1)
        left = [name for name, p in pids.items() if psutil.pid_exists(p)
                and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        if left:
            report.problems.append(f"nodes outlived their SIGKILLed launcher by 20 s: {left}")
        with contextlib.suppress(Exception):
            self.graph.proc.wait(5)
        from perch_common.ros.servers import server_endpoints

        services = [self.node.resolve_service_name(s[0]) for s in NODE_SERVICES.values()]
        while time.monotonic() < deadline + 10 and any(server_endpoints(self.node, s) for s in services):
            time.sleep(0.1)   # a new launcher refuses to start beside the old graph's last endpoints
        self.graph = launched(self.work, self.node)

    def _next_mission(self, report: FaultReport) -> None:
        from perch_operator.api.client import run_mission

        missing = self._wait_whole()
        if missing:
            report.problems.append(f"the graph did not come back: {missing}")
            return
        report.missions += 1
        try:
            result = run_mission(self.node, self.goal, timeout=120)
        except Exception as exc:  # noqa: BLE001 - reported as this mission's problem
            report.problems.append(f"the mission after a kill failed: {type(exc).__name__}: {exc}")
            return
        if result.success:
            report.next_ok += 1
        else:
            report.problems.append(f"the mission after a kill failed: {result.message}")

    def _wait_whole(self, timeout: float = 90.0) -> list[str]:
        """Wait until every node runs again and each service has exactly live servers (a killed one's
        endpoints have left the graph after the lease); returns what is still missing."""
        from perch_common.ros.servers import server_endpoints
        from perch_operator.api.client import GoalStatusWatch

        services = {n: self.node.resolve_service_name(s[0]) for n, s in NODE_SERVICES.items()}
        deadline = time.monotonic() + timeout
        missing = list(services)
        while time.monotonic() < deadline:
            pids = self.graph.pids()
            status = GoalStatusWatch.writers_of(self.node)
            missing = [n for n, s in services.items()
                       if n not in pids or len(server_endpoints(self.node, s)) != 1]
            if len(status) != 1:
                missing.append("the coordinator's action server")
            if not missing:
                return []
            time.sleep(0.1)
        return missing


def register_faults(p) -> None:
    """`perch bench soak --faults N`'s options."""
    from perch_common.cli_types import non_negative_int

    p.add_argument("--faults", type=non_negative_int, default=0,
                   help="instead: N >= 0 missions each with a stage node, the coordinator or the launcher SIGKILLed "
                        "mid-mission (seeded), each followed by an ordinary mission")


def left_behind() -> tuple[list[int], list[Path]]:
    """After the graph stopped: Perch node processes still running on this domain, and Fast DDS
    shared-memory files of dead processes."""
    import psutil

    from perch_common.processes import dead_shm_files

    orphans = [p.pid for p in psutil.process_iter(["cmdline", "environ"])
               if _perch_node(p) and p.info["environ"] and p.info["environ"].get("ROS_DOMAIN_ID")
               == os.environ.get("ROS_DOMAIN_ID")]
    return orphans, dead_shm_files(min_age=0.0)


def leftover_problems(orphans: list[int], dead_shm: list[Path]) -> list[str]:
    """left_behind's findings as problems of the soak (none when nothing was left)."""
    problems = [f"node processes left running: {orphans}"] if orphans else []
    return problems + ([f"/dev/shm files of dead processes: {[p.name for p in dead_shm]}"] if dead_shm else [])


def _perch_node(process) -> bool:
    cmd = process.info["cmdline"] or []
    return "-m" in cmd and cmd[cmd.index("-m") + 1].split(".")[0] in (*NODE_SERVICES, "perch_common")
