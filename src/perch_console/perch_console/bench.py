"""`perch bench console`: how soon the console shows the room, and what it costs in CPU.

    perch bench console --mesh ../shared/data/meshes/apartment.ply \\
        --target ../shared/data/meshes/apartment_target.ply:1.2 --json

Starts a graph (one process) on this ROS domain, then `perch console --mesh M` as its own process,
and opens the printed URL in Debian's chromium (Playwright) at once. JSON fields:
  console_ready_s   `perch console` started to its URL printed (viser serving, the room in its scene);
  first_picture_s   `perch console` started to the first browser frame showing the room (screenshots
                    polled until 6 % of the 3D view is no longer the empty background: the apartment
                    seen from above fills ~12 %, an empty view ~1 % with viser's notices);
  idle_cpu_pct      the console process's CPU (% of one core) over --idle seconds with a browser open
                    and no mission;
  mission_cpu_pct   the same while a mission runs (auto-accept; started by this benchmark's own action
                    client, the console only watches): goal sent to result, plus the views that follow;
  graph_cpu_pct     the graph process's CPU over the same mission window, for scale;
  mission_s         that window's length.
The browser's own CPU is not counted (it is the operator's machine in use).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

STAGE_NODES = ["perch_operator", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement"]
SERVICES = ["perch/crop", "perch/clean_mesh", "perch/segment", "perch/filter", "perch/optimise"]


def register(sub) -> None:
    """The `perch bench console` benchmark."""
    from perch_common.cli_types import int_between, positive_float
    from perch_operator.bench import camera_count

    p = sub.add_parser("console", help="the console: time to the first picture of the room, CPU idle and in a mission")
    p.add_argument("--mesh", type=Path, required=True, help="the scan the console shows and the mission plans on")
    p.add_argument("--target", default=None, metavar="SPEC", help="as for perch plan (default: the cropped floor)")
    p.add_argument("--cameras", type=camera_count, default=4, help="cameras of the mission (0: the node's default)")
    p.add_argument("--idle", type=positive_float, default=10.0, help="seconds of idle CPU measurement (> 0)")
    p.add_argument("--port", type=int_between(0, 65535), default=8097, help="the console's port (0: a free one)")
    p.add_argument("--json", action="store_true", help="print JSON (always on; accepted for uniformity)")
    p.set_defaults(func=_run)


def _perch_command() -> list[str]:
    exe = Path(sys.executable).with_name("perch")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "perch_common.cli"]


def room_drawn(png: bytes, panel_fraction: float = 0.3) -> bool:
    """Whether a screenshot's 3D view (left of the panel) shows geometry: 6 % of its pixels differ
    from the background colour (the most common colour of its top and bottom rows)."""
    import cv2

    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    view = image[:, : int(image.shape[1] * (1 - panel_fraction))].astype(np.int16)
    border = np.concatenate([view[0], view[-1]])
    colours, counts = np.unique(border, axis=0, return_counts=True)
    background = colours[np.argmax(counts)]
    return float(np.mean(np.abs(view - background).sum(axis=2) > 24)) > 0.06


def _cpu_seconds(pid: int) -> float:
    import psutil

    process = psutil.Process(pid)
    total = process.cpu_times().user + process.cpu_times().system
    for child in process.children(recursive=True):
        try:
            times = child.cpu_times()
            total += times.user + times.system
        except psutil.NoSuchProcess:
            pass
    return total


def _run(args) -> int:
    import rclpy
    from playwright.sync_api import sync_playwright

    from perch_common.launch import CONTAINER, GraphProcesses
    from perch_common.mesh import load_mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_interfaces.action import PlanPerches
    from perch_operator.api.client import run_mission
    from perch_operator.cli.plan import parse_target
    from perch_operator.cli.runner import client_context

    chromium = Path("/usr/bin/chromium")
    if not chromium.exists():
        print("perch bench console: needs Debian's chromium (apt-get install -y chromium)", file=sys.stderr)
        return 2
    report: dict = {"mesh": str(args.mesh), "load_1min": os.getloadavg()[0]}
    with client_context():
        node = rclpy.create_node("perch_bench_console")
        graph = GraphProcesses(None, STAGE_NODES, mode="one-process").start()
        console = None
        try:
            missing = graph.wait_for_services(node, ["/" + s for s in SERVICES], timeout=120)
            if missing:
                raise RuntimeError(f"graph did not start: {missing}")
            started = time.monotonic()
            console = subprocess.Popen([*_perch_command(), "console", "--mesh", str(args.mesh), "--port",
                                        str(args.port)], stdout=subprocess.PIPE, text=True)
            url = ""
            for line in console.stdout:
                if line.startswith("perch console: http"):
                    url = line.split()[2]
                    break
            if not url:
                raise RuntimeError("perch console exited before serving")
            report["console_ready_s"] = round(time.monotonic() - started, 3)
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=str(chromium), args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(url)
                deadline = time.monotonic() + 300
                while not room_drawn(page.screenshot()) and time.monotonic() < deadline:
                    pass
                report["first_picture_s"] = round(time.monotonic() - started, 3)
                page.get_by_role("button", name="Start mission").wait_for(timeout=60_000)
                before, t0 = _cpu_seconds(console.pid), time.monotonic()
                time.sleep(args.idle)   # the measurement window itself (a benchmark, not a test)
                report["idle_cpu_pct"] = round(100 * (_cpu_seconds(console.pid) - before) / (time.monotonic() - t0), 2)
                mesh = load_mesh(args.mesh)
                goal = PlanPerches.Goal(mesh=mesh_to_msg(mesh), num_cameras=args.cameras, auto_accept=True, seed=-1)
                goal.target = parse_target(args.target)
                container = graph.processes[CONTAINER].pid
                before, graph_before, t0 = _cpu_seconds(console.pid), _cpu_seconds(container), time.monotonic()
                result = run_mission(node, goal, timeout=600)
                page.get_by_text("Stage: done").wait_for(timeout=120_000)   # the console has shown the result
                window = time.monotonic() - t0
                report["mission_s"] = round(window, 3)
                report["mission_ok"] = bool(result.success)
                report["mission_cpu_pct"] = round(100 * (_cpu_seconds(console.pid) - before) / window, 2)
                report["graph_cpu_pct"] = round(100 * (_cpu_seconds(container) - graph_before) / window, 2)
                browser.close()
        finally:
            if console is not None:
                console.terminate()
                console.wait(timeout=30)
            graph.stop()
            node.destroy_node()
    print(json.dumps(report, indent=2))
    return 0
