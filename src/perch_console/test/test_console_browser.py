"""The console in a real browser: Debian's chromium driven by Playwright against a running graph.

Open the console, set a target box (typed, then one face dragged with the mouse), start a mission
(with a surface review) on a generated room, reject one surface and crop another, reject one
proposal, accept the rest, and check that the waypoints published on
perch/mission_waypoints are the accepted perches the console showed. Every wait is on a page or
graph condition (Playwright's auto-waiting locators, polled topics), never a fixed sleep. Each edit
is waited for in the console (the server) before the next: viser's client sends its GUI messages
through one 50 ms throttle that keeps only the latest, so an edit followed within 50 ms by another
is never sent (a CI run planned 4 cameras while the page showed 3). Screenshots
of each step go to perch-console-shots/ in the temporary folder; with PERCH_UPDATE_DOC_SCREENSHOTS=1 they replace the
README's in src/perch_console/doc/ (a plain test run leaves the checkout as it was).
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CHROMIUM = "/usr/bin/chromium"
DOC = Path(__file__).resolve().parents[1] / "doc"
UPDATE_DOC = os.environ.get("PERCH_UPDATE_DOC_SCREENSHOTS") == "1"
SHOTS = DOC if UPDATE_DOC else Path(tempfile.gettempdir()) / "perch-console-shots"
# The README's screenshots at their size; otherwise a smaller page: chromium draws the scene in software
# (swiftshader) on every frame, with both cores, and the whole flow took 449 s at 1440x900, 326 s at 960x600.
VIEWPORT = {"width": 1440, "height": 900} if UPDATE_DOC else {"width": 960, "height": 600}
STAGE_NODES = ["perch_operator", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement"]
SERVICES = ["/perch/crop", "/perch/clean_mesh", "/perch/segment", "/perch/filter", "/perch/optimise"]
CAMERAS = 3
WAIT_MS = 180_000   # generous: CI has 2 cores and a software-rendered WebGL
DRAG_ATTEMPTS, DRAG_WAIT_S = 3, 40.0   # drags of a face handle, and how long each may take to move the box


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
    SHOTS.mkdir(exist_ok=True)
    page.screenshot(path=str(SHOTS / name))


def review_choice(console_obj, label: str):
    """The console's own dropdown for a reviewed surface, by the label the page shows."""
    return next(h for h in console_obj._review_handles if getattr(h, "label", None) == label.strip())


def until(condition, what: str, timeout: float = WAIT_MS / 1000, page=None):
    """Poll `condition` (a page's event loop kept running) until it holds; its value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if page is not None:
            page.wait_for_timeout(50)
        else:
            time.sleep(0.05)
    raise TimeoutError(f"timed out waiting for {what}")


def screen_point(page, camera, point) -> tuple[float, float]:
    """Where a world point appears on the page: the browser's own camera (pose in OpenCV convention,
    vertical field of view, canvas size, as it reports them to viser) projected onto the canvas."""
    from perch_console.state import EditBox

    rotation = EditBox(np.zeros(3), np.ones(3), camera.wxyz).rotation     # world from camera
    x, y, z = rotation.T @ (np.asarray(point, np.float64) - camera.position)
    focal = camera.image_height / 2 / np.tan(camera.fov / 2)
    canvas = max((c.bounding_box() for c in page.locator("canvas").all()), key=lambda b: b["width"] * b["height"])
    scale = canvas["width"] / camera.image_width
    return (canvas["x"] + scale * (camera.image_width / 2 + focal * x / z),
            canvas["y"] + scale * (camera.image_height / 2 + focal * y / z))


def drag_face(page, console_obj, editor, axis: int, sign: float, pixels: float, attempt: int = 1) -> None:
    """Drag one face handle of a box along its arrow with the mouse, as an operator does: the view
    is first turned to look at that face from above and in front (a little further away on each
    attempt), then the arrow is grabbed and pulled `pixels` along its direction on the screen."""
    client = until(lambda: next(iter(console_obj.server.get_clients().values()), None), "the browser's client")
    box = console_obj.box_of(editor)
    face, direction = box.face(axis, sign), box.rotation[:, axis]
    # A new pose on every attempt, so the browser always has a change to report back (a drag that
    # missed the arrow orbited the view instead, and the same pose set again may be no change at all).
    eye = face + np.array([0.3, -2.4, 1.8]) * (1.0 + 0.05 * (attempt - 1))
    client.camera.up_direction = (0.0, 0.0, 1.0)
    client.camera.position = tuple(eye)
    client.camera.look_at = tuple(face)
    # viser's setters change the server's copy of the camera at once and only queue the change for
    # the page; the copy is replaced by a new one when the page reports its camera. Wait for that
    # report to show the pose, or the arrow is looked for where the page does not show it yet (a
    # loaded rehearsal's three drags all missed, each orbiting the view away again).
    ours = client.camera._state
    until(lambda: client.camera._state is not ours
          and np.allclose(client.camera.position, eye, atol=1e-3)
          and np.allclose(client.camera.look_at, face, atol=1e-3),
          "the browser to report its camera at the face", page=page)
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")   # drawn
    camera = client.camera
    grab = np.array(screen_point(page, camera, face + 0.12 * direction))   # on the arrow's shaft (0.3 m long)
    tip = np.array(screen_point(page, camera, face + 0.3 * direction))
    along = (tip - grab) / np.linalg.norm(tip - grab)
    page.mouse.move(*grab)
    page.mouse.down()
    for step in range(1, 11):   # in steps, as a hand moves: the gizmo follows each pointer move
        page.mouse.move(*(grab + along * pixels * step / 10))
    page.mouse.up()


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
        page = browser.new_page(viewport=VIEWPORT)
        page.set_default_timeout(WAIT_MS)
        page.goto(url)
        # 1. the room is there, with the target box on it
        page.get_by_role("button", name="Start mission").wait_for()
        page.get_by_text("Stage: idle").wait_for()
        text_field(page, "Your name").fill("alice")   # who decides, as the log and the reasons say
        text_field(page, "Your name").press("Tab")
        until(lambda: [f.value for f in console_obj._names.values()] == ["alice"], "the name to reach the console",
              page=page)
        shot(page, "console_1_open.png")
        # 2. set the target box (the fields and the 3D handles move together) and ask for a surface review
        low, high = scene.mesh.vertices.min(axis=0), scene.mesh.vertices.max(axis=0)
        center = (low + high) / 2
        center[2] = low[2] + 1.0
        size = [(high[0] - low[0]) * 0.5, (high[1] - low[1]) * 0.5, 1.6]
        set_vector(page, "Target centre", center)
        until(lambda: np.allclose(console_obj.box_of(console_obj.target).center, center, atol=0.01),
              "the target centre to reach the console", page=page)
        set_vector(page, "Target size", size)
        until(lambda: np.allclose(console_obj.box_of(console_obj.target).size, size, atol=0.01),
              "the target size to reach the console", page=page)
        page.get_by_label("Cameras").fill(str(CAMERAS))
        page.get_by_label("Cameras").press("Tab")
        until(lambda: int(console_obj.cameras.value) == CAMERAS, "the camera count to reach the console", page=page)
        page.get_by_label("Review largest surfaces").fill("3")
        page.get_by_label("Review largest surfaces").press("Tab")
        until(lambda: int(console_obj.review_count.value) == 3, "the review count to reach the console", page=page)
        # then drag the box's +x face handle outwards: the box grows along x, its -x face stays
        typed = console_obj.box_of(console_obj.target)

        def grown():
            box = console_obj.box_of(console_obj.target)
            return box if box.size[0] > typed.size[0] + 0.05 else None

        # A drag can miss the arrow on a loaded machine (a rehearsal's did: the box never moved in 180 s);
        # the operator then drags again. A drag that landed late only grows the box more.
        for attempt in range(1, DRAG_ATTEMPTS + 1):
            drag_face(page, console_obj, console_obj.target, 0, 1.0, 90, attempt)
            try:
                until(grown, f"the dragged face to resize the target box (drag {attempt} of {DRAG_ATTEMPTS})",
                      timeout=DRAG_WAIT_S, page=page)
                break
            except TimeoutError:
                if attempt == DRAG_ATTEMPTS:
                    raise
        until(lambda: abs(float(vector_inputs(page, "Target size").nth(0).input_value())
                          - console_obj.box_of(console_obj.target).size[0]) < 0.01,
              "the size field to follow the handle", page=page)
        dragged = console_obj.box_of(console_obj.target)
        np.testing.assert_allclose(dragged.face(0, -1.0), typed.face(0, -1.0), atol=1e-6)
        np.testing.assert_allclose(dragged.size[1:], typed.size[1:], atol=1e-6)
        shot(page, "console_2_target.png")
        page.get_by_role("button", name="Start mission").click()
        page.get_by_text(f"mission started by alice: {CAMERAS} camera(s), review of the 3 largest surfaces").wait_for()
        # 3. the surface review: reject the first (largest) surface, crop the second to 60 % of its
        #    length (its crop box starts around it; the size is typed here), approve the rest
        page.get_by_role("button", name="Submit review").wait_for()
        labels = page.locator("xpath=//label[starts-with(normalize-space(), 'S')][contains(., 'm²')]")
        surface_label, crop_label = labels.nth(0).inner_text(), labels.nth(1).inner_text()
        page.get_by_label(surface_label).click()
        page.get_by_role("option", name="reject").click()
        until(lambda: review_choice(console_obj, surface_label).value == "reject", "the rejection to reach the console",
              page=page)
        page.get_by_label(crop_label).click()
        page.get_by_role("option", name="crop").click()
        until(lambda: review_choice(console_obj, crop_label).value == "crop", "the crop choice to reach the console",
              page=page)
        cropped = int(re.match(r"S(\d+)", crop_label.strip()).group(1))
        editor = until(lambda: console_obj._crop_editors.get(cropped), "the crop box of the second surface")
        whole = console_obj.box_of(editor)
        vector_inputs(page, f"S{cropped} crop size").nth(0).fill(f"{0.6 * whole.size[0]:.3f}")
        vector_inputs(page, f"S{cropped} crop size").nth(0).press("Tab")
        until(lambda: abs(console_obj.box_of(editor).size[0] - 0.6 * whole.size[0]) < 0.01,
              "the crop size to reach the console", page=page)
        text_field(page, "Reason").fill("segmentation ran over the door")
        until(lambda: console_obj.reason.value == "segmentation ran over the door", "the reason to reach the console",
              page=page)
        shot(page, "console_3_review.png")
        page.get_by_role("button", name="Submit review").click()
        page.get_by_text(re.compile(rf"decided surface review \d+, rejecting \[\d+\], cropping \[{cropped}\]"
                                    r" \(segmentation ran over the door\): ok")).wait_for()
        # 4. proposals: reject the first with a reason, accept the rest (and any re-plan) until none is open
        page.get_by_role("button", name=re.compile(r"^Accept #\d+$")).first.wait_for()
        deadline = time.monotonic() + WAIT_MS / 1000
        while len(open_buttons(page)) < CAMERAS and time.monotonic() < deadline:   # all of them listed
            page.wait_for_timeout(50)
        proposals = open_buttons(page)
        shot(page, "console_4_proposals.png")
        rejected = proposals[0]
        text_field(page, "Reason").fill("blocks the door")
        until(lambda: console_obj.reason.value == "blocks the door", "the reason to reach the console", page=page)
        page.get_by_role("button", name=f"Reject #{rejected}").click()
        page.get_by_text(f"alice rejected proposal {rejected} (blocks the door): ok").wait_for()
        # a second browser watching sees the same mission and who decided, without deciding itself
        watcher = browser.new_page(viewport=VIEWPORT)
        watcher.set_default_timeout(WAIT_MS)
        watcher.goto(url)
        watcher.get_by_text(f"alice rejected proposal {rejected} (blocks the door): ok").wait_for()
        assert watcher.get_by_role("button", name=f"Reject #{rejected}").count() == 0   # decided for all
        watcher.close()
        accepted: list[int] = []
        text_field(page, "Reason").fill("")
        until(lambda: console_obj.reason.value == "", "the reason to reach the console", page=page)
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
