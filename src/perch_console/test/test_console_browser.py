"""The console in a real browser: Debian's chromium driven by Playwright against a running graph.

Open the console, set a target box, start a mission (with a surface review) on a generated room,
reject one surface, reject one proposal, accept the rest, and check that the waypoints published on
perch/mission_waypoints are the accepted perches the console showed. Every wait is on a page or
graph condition (Playwright's auto-waiting locators, polled topics), never a fixed sleep. Screenshots
of each step go to src/perch_console/doc/ (the README shows them).
"""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CHROMIUM = "/usr/bin/chromium"
DOC = Path(__file__).resolve().parents[1] / "doc"
STAGE_NODES = ["perch_operator", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement"]
SERVICES = ["/perch/crop", "/perch/clean_mesh", "/perch/segment", "/perch/filter", "/perch/optimise"]
CAMERAS = 3
WAIT_MS = 180_000   # generous: CI has 2 cores and a software-rendered WebGL


def browser_or_skip():
    if not Path(CHROMIUM).exists() and shutil.which("chromium") is None:
        pytest.skip("Debian's chromium is not installed (apt-get install -y chromium; make setup does it as root)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (requirements.in; make setup)")
    return sync_playwright, Path(CHROMIUM) if Path(CHROMIUM).exists() else Path(shutil.which("chromium"))


@pytest.fixture(scope="module")
def graph(tmp_path_factory):
    """Every stage node in one process on an isolated domain, and rclpy initialised in this one."""
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    from perch_common.launch import GraphProcesses

    tmp = tmp_path_factory.mktemp("console_graph")
    rclpy.init()
    processes = GraphProcesses(None, STAGE_NODES, log_dir=tmp / "logs", mode="one-process")
    processes.start()
    node = rclpy.create_node("console_test")
    try:
        missing = processes.wait_for_services(node, SERVICES, timeout=120)
        assert not missing, f"services did not start: {missing}; logs in {tmp / 'logs'}"
        yield node
    finally:
        processes.stop()
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture(scope="module")
def console(graph, tmp_path_factory):
    from perch_console.cli import start_console

    from perch_common.mesh import save_mesh
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(3, "room")
    path = save_mesh(tmp_path_factory.mktemp("console") / "room.ply", scene.mesh)
    console, client, url = start_console(path, "127.0.0.1", port=0)
    try:
        yield console, url, scene
    finally:
        client.close()
        console.server.stop()


def vector_inputs(page, label: str):
    """The three number inputs of a viser vector field."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class,"
                        "'mantine-Flex-root')][1]//input")


def text_field(page, label: str):
    """The input of a viser text field."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class,"
                        "'mantine-Flex-root')][1]//input").first


def set_vector(page, label: str, values) -> None:
    inputs = vector_inputs(page, label)
    for i, value in enumerate(values):
        inputs.nth(i).fill(f"{value:.2f}")
        inputs.nth(i).press("Tab")


def shot(page, name: str) -> None:
    from perch_console.cli import dismiss_notices

    dismiss_notices(page)   # viser's software-WebGL notice, shown again whenever the renderer restarts
    DOC.mkdir(exist_ok=True)
    page.screenshot(path=str(DOC / name))


def open_buttons(page) -> list[int]:
    """Proposal ids with an Accept button (open proposals), as the page shows them now."""
    return sorted(int(m) for m in re.findall(r"Accept #(\d+)", " ".join(
        page.get_by_role("button", name=re.compile(r"^Accept #\d+$")).all_inner_texts())))


def test_first_time_operator_flow_in_chromium(graph, console):

    from perch_interfaces import msg as pm
    from perch_operator.cli.runner import spin_for
    from perch_operator.coordinator.node import LATCHED_LAST

    sync_playwright, chromium = browser_or_skip()
    console_obj, url, scene = console
    sets: list = []
    sub = graph.create_subscription(pm.PerchWaypointSet, "/perch/mission_waypoints", sets.append, LATCHED_LAST)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(chromium), args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.set_default_timeout(WAIT_MS)
        page.goto(url)
        # 1. the room is there, with the target box on it
        page.get_by_role("button", name="Start mission").wait_for()
        page.get_by_text("Stage: idle").wait_for()
        text_field(page, "Your name").fill("alice")   # who decides, as the log and the reasons say
        text_field(page, "Your name").press("Tab")
        shot(page, "console_1_open.png")
        # 2. set the target box (the fields and the 3D handles move together) and ask for a surface review
        low, high = scene.mesh.vertices.min(axis=0), scene.mesh.vertices.max(axis=0)
        center = (low + high) / 2
        center[2] = low[2] + 1.0
        size = [(high[0] - low[0]) * 0.5, (high[1] - low[1]) * 0.5, 1.6]
        set_vector(page, "Target centre", center)
        set_vector(page, "Target size", size)
        page.get_by_label("Cameras").fill(str(CAMERAS))
        page.get_by_label("Cameras").press("Tab")
        page.get_by_label("Review largest surfaces").fill("3")
        page.get_by_label("Review largest surfaces").press("Tab")
        box = console_obj.box_of(console_obj.target)
        deadline = time.monotonic() + WAIT_MS / 1000
        while (abs(box.size[0] - size[0]) > 0.01 or int(console_obj.review_count.value) != 3) \
                and time.monotonic() < deadline:   # the browser's edits reached the server
            page.wait_for_timeout(50)
            box = console_obj.box_of(console_obj.target)
        assert abs(box.center[0] - center[0]) < 0.01 and abs(box.size[1] - size[1]) < 0.01
        shot(page, "console_2_target.png")
        page.get_by_role("button", name="Start mission").click()
        page.get_by_text("mission started by alice").wait_for()
        # 3. the surface review: reject the first (largest) surface, approve the rest
        page.get_by_role("button", name="Submit review").wait_for()
        first = page.locator("xpath=//label[starts-with(normalize-space(), 'S')][contains(., 'm²')]").first
        surface_label = first.inner_text()
        page.get_by_label(surface_label).click()
        page.get_by_role("option", name="reject").click()
        text_field(page, "Reason").fill("segmentation ran over the door")
        shot(page, "console_3_review.png")
        page.get_by_role("button", name="Submit review").click()
        page.get_by_text(re.compile(r"decided surface review \d+, rejecting \[\d+\]")).wait_for()
        # 4. proposals: reject the first with a reason, accept the rest (and any re-plan) until none is open
        page.get_by_role("button", name=re.compile(r"^Accept #\d+$")).first.wait_for()
        deadline = time.monotonic() + WAIT_MS / 1000
        while len(open_buttons(page)) < CAMERAS and time.monotonic() < deadline:   # all of them listed
            page.wait_for_timeout(50)
        proposals = open_buttons(page)
        shot(page, "console_4_proposals.png")
        rejected = proposals[0]
        text_field(page, "Reason").fill("blocks the door")
        page.get_by_role("button", name=f"Reject #{rejected}").click()
        page.get_by_text(f"alice rejected proposal {rejected} (blocks the door): ok").wait_for()
        # a second browser watching sees the same mission and who decided, without deciding itself
        watcher = browser.new_page(viewport={"width": 1280, "height": 800})
        watcher.set_default_timeout(WAIT_MS)
        watcher.goto(url)
        watcher.get_by_text(f"alice rejected proposal {rejected} (blocks the door): ok").wait_for()
        assert watcher.get_by_role("button", name=f"Reject #{rejected}").count() == 0   # decided for all
        watcher.close()
        accepted: list[int] = []
        text_field(page, "Reason").fill("")
        deadline = time.monotonic() + WAIT_MS / 1000
        while time.monotonic() < deadline:
            page.get_by_text(re.compile(r"Stage: (done|failed)|Accept #\d+")).first.wait_for()
            ids = [i for i in open_buttons(page) if i not in accepted and i != rejected]
            if not ids:
                if page.get_by_text(re.compile(r"Stage: (done|failed)")).count():
                    break
                page.wait_for_timeout(50)
                continue
            page.get_by_role("button", name=f"Accept #{ids[0]}").click()
            page.get_by_text(f"accepted proposal {ids[0]}: ok").wait_for()
            accepted.append(ids[0])
        page.get_by_text("Stage: done").wait_for()
        shot(page, "console_5_done.png")
        table = page.locator("xpath=//table[.//th[normalize-space()='proposal']]").last
        shown = [[c.strip() for c in row.split("\t")] for row in table.locator("tbody tr").all_inner_texts()]
        browser.close()
    # 5. what the console showed is what went out on perch/mission_waypoints
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not (sets and len(sets[-1].waypoints) == len(accepted)):
        spin_for(graph, 0.1)
    graph.destroy_subscription(sub)
    assert len(accepted) == CAMERAS and rejected not in accepted
    published = sorted((w.proposal_id, w.drone_index, w.pose.pose.position.x, w.pose.pose.position.y,
                        w.pose.pose.position.z) for w in sets[-1].waypoints)
    assert [int(r[0]) for r in shown] == [p[0] for p in published] == sorted(accepted)
    for row, (pid, drone, x, y, z) in zip(shown, published):
        assert int(row[1]) == drone
        assert [float(v) for v in row[2:5]] == pytest.approx([x, y, z], abs=1.5e-3)
    log = [d.line() for d in console_obj.desk.log]
    assert any(line.split()[1:4] == ["alice", "rejected", "proposal"] and f"proposal {rejected} " in line
               for line in log)
