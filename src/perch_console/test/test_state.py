"""The console's pure parts: box handles, serialised decisions, texts, the token gate and marker merging."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from perch_console.state import (
    FACES,
    MIN_BOX_SIZE,
    DecisionDesk,
    EditBox,
    floor_hit,
    footprint_triangles,
    quaternion_wxyz,
    removal_table,
    shortfall_of,
    surface_box,
    waypoint_rows,
)


def test_corner_handle_resizes_and_keeps_the_opposite_corner():
    box = EditBox([1.0, 2.0, 1.0], [2.0, 2.0, 2.0])
    assert np.allclose(box.corner(), [2.0, 3.0, 2.0])
    grown = box.resized_to([3.0, 3.5, 2.5])
    assert np.allclose(grown.size, [3.0, 2.5, 2.5]) and np.allclose(grown.center, [1.5, 2.25, 1.25])
    assert np.allclose(grown.center - grown.size / 2, box.center - box.size / 2)   # the opposite corner stays
    flat = box.resized_to([-5.0, 3.0, 2.0])   # dragged past the opposite corner: clamped, not inverted
    assert flat.size[0] == pytest.approx(0.05)


def test_a_turned_box_resizes_along_its_own_axes():
    quarter = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])   # 90 deg about z
    box = EditBox([0.0, 0.0, 0.0], [2.0, 1.0, 1.0], quarter)
    assert np.allclose(box.corner(), [-0.5, 1.0, 0.5])   # its x axis points along world y
    assert box.contains(np.array([[0.0, 0.9, 0.0], [0.9, 0.0, 0.0]])).tolist() == [True, False]
    assert box.describe().endswith("(rotated)") and EditBox([0, 0, 1], [1, 2, 3]).describe() == \
        "box:0.00,0.00,1.00,1.00,2.00,3.00"


def test_face_handles_move_one_face_and_keep_the_opposite_one():
    box = EditBox([1.0, 2.0, 1.0], [2.0, 4.0, 2.0])
    np.testing.assert_allclose(box.face(0, 1.0), [2.0, 2.0, 1.0])
    np.testing.assert_allclose(box.face(1, -1.0), [1.0, 0.0, 1.0])
    # the +x face dragged out by 0.5 m (the handle's sideways drift is ignored): -x face stays at x = 0
    grown = box.face_moved(0, 1.0, [2.5, 9.0, -3.0])
    np.testing.assert_allclose(grown.size, [2.5, 4.0, 2.0])
    np.testing.assert_allclose(grown.center, [1.25, 2.0, 1.0])
    # the -y face dragged in by 1 m: +y face stays at y = 4
    shrunk = box.face_moved(1, -1.0, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(shrunk.size, [2.0, 3.0, 2.0])
    np.testing.assert_allclose(shrunk.center, [1.0, 2.5, 1.0])
    # dragged past the opposite face: the box keeps its minimum size instead of turning inside out
    flat = box.face_moved(2, 1.0, [1.0, 2.0, -5.0])
    np.testing.assert_allclose(flat.size[2], MIN_BOX_SIZE)
    np.testing.assert_allclose(flat.center[2] - flat.size[2] / 2, 0.0, atol=1e-12)
    assert len(FACES) == 6 and len(set(FACES)) == 6


def test_face_handles_of_a_turned_box_work_along_its_axes():
    quarter = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])   # 90 deg about z: box x = world y
    box = EditBox([0.0, 0.0, 0.0], [2.0, 1.0, 1.0], quarter)
    np.testing.assert_allclose(box.face(0, 1.0), [0.0, 1.0, 0.0], atol=1e-12)
    moved = box.face_moved(0, 1.0, [0.3, 2.0, 0.0])    # world y 2: box x grows to 3
    np.testing.assert_allclose(moved.size, [3.0, 1.0, 1.0])
    np.testing.assert_allclose(moved.center, [0.0, 0.5, 0.0], atol=1e-12)


def test_a_surface_box_wraps_its_outline_turned_with_it():
    from perch_common.types import PlaneFrame

    # a wall facing -y at y = 3, u along x, v up (u x v = -y... so the normal is -y)
    frame = PlaneFrame(np.array([1.0, 3.0, 1.5]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]),
                       np.array([0, -1.0, 0]))
    outline = [[np.array([[-1.0, -1.0], [2.0, -1.0], [2.0, 1.0], [-1.0, 1.0]])]]
    box = surface_box(frame, outline, thickness=0.2)
    np.testing.assert_allclose(box.size, [3.0, 2.0, 0.2])
    np.testing.assert_allclose(box.center, [1.5, 3.0, 1.5])
    corners = frame.to_world(outline[0][0])
    assert box.contains(corners * 0.999 + box.center * 0.001).all()
    np.testing.assert_allclose(box.rotation[:, 2], [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(quaternion_wxyz(np.eye(3)), [1, 0, 0, 0])


def test_floor_clicks_make_a_footprint():
    up = np.array([0.0, 0.0, 1.0])
    hit = floor_hit([1.0, 1.0, 3.0], [0.5, 0.0, -1.0], up, 0.5)
    np.testing.assert_allclose(hit, [2.25, 1.0, 0.5])
    assert floor_hit([0, 0, 3.0], [1.0, 0, 0], up, 0.5) is None      # parallel to the floor
    assert floor_hit([0, 0, 3.0], [0, 0, 1.0], up, 0.5) is None      # looking up, away from it
    # an L-shaped footprint (concave): its triangles cover exactly its 3 m^2 and stay on the floor
    clicks = np.array([[0, 0, 0.5], [2, 0, 0.5], [2, 1, 0.5], [1, 1, 0.5], [1, 2, 0.5], [0, 2, 0.5]], float)
    vertices, triangles = footprint_triangles(clicks, up)
    tri = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(3.0, abs=1e-9)
    np.testing.assert_allclose(vertices[:, 2], 0.5, atol=1e-12)
    assert not ((tri.mean(axis=1)[:, 0] > 1.0) & (tri.mean(axis=1)[:, 1] > 1.0)).any()   # the notch stays empty
    with pytest.raises(ValueError, match="at least 3 points"):
        footprint_triangles(clicks[:2], up)
    with pytest.raises(ValueError, match="no area"):
        footprint_triangles(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), up)


def test_decisions_are_serialised_and_remember_who():
    desk = DecisionDesk()
    inside = []
    overlap = []

    def call(i):
        def run():
            overlap.append(len(inside))
            inside.append(i)
            threading.Event().wait(0.01)
            inside.remove(i)
            return True, f"done {i}"
        return run

    threads = [threading.Thread(target=lambda i=i: desk.decide(f"op{i}", "accepted", f"proposal {i}", "", call(i), i))
               for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert max(overlap) == 0   # never two decisions at once
    assert sorted(desk.by_proposal) == list(range(6)) and desk.by_proposal[3].who == "op3"
    refused = desk.decide("bob", "rejected", "proposal 9", "door", lambda: (_ for _ in ()).throw(TimeoutError("late")), 9)
    assert not refused.success and 9 not in desk.by_proposal and "bob rejected proposal 9 (door): refused: late" in refused.line()


def test_shortfall_and_tables():
    assert shortfall_of("placed 4 cameras, fitness 0.8") == ""
    assert shortfall_of("only 2 of 4 cameras fit: the regions hold 2 perches 1.0 m apart. placed 2 cameras") == \
        "only 2 of 4 cameras fit: the regions hold 2 perches 1.0 m apart."
    from perch_interfaces import msg as pm

    removal = pm.FilterRemoval(surface_id=5, area_total=4.0, area_kept=1.0, line_of_sight=3.0)
    table = removal_table([removal, pm.FilterRemoval(surface_id=6, area_total=1.0, area_kept=1.0)],
                          ("orientation", "line_of_sight"))
    rows = table.splitlines()
    assert rows[0] == "| surface | total | kept | orientation | line of sight |"
    assert rows[2] == "| S5 | 4.00 | 1.00 |  | 3.00 |" and rows[3].startswith("| S6 |")
    accepted = pm.Proposal(id=7, status=pm.Proposal.STATUS_ACCEPTED)
    accepted.placement.drone_index, accepted.placement.drone_pose.position.x = 2, 1.5
    assert waypoint_rows({7: accepted, 8: pm.Proposal(id=8)}) == [(7, 2, 1.5, 0.0, 0.0)]


def test_token_gate_serves_only_under_the_token():
    import http

    import websockets.asyncio.server as ws_server
    from perch_console.cli import is_loopback, require_token
    from websockets.datastructures import Headers
    from websockets.http11 import Request

    seen = []
    original = ws_server.serve
    ws_server.serve = lambda handler, *a, process_request=None, **k: process_request
    try:
        require_token("s3cret")
        check = ws_server.serve(None, process_request=lambda conn, req: seen.append(req.path))
    finally:
        ws_server.serve = original
    assert check(None, Request("/", Headers())).status_code == http.HTTPStatus.FORBIDDEN
    assert check(None, Request("/other/?x=s3cret", Headers())).status_code == http.HTTPStatus.FORBIDDEN
    assert check(None, Request("/s3cret/?darkMode", Headers())) is None and seen == ["/?darkMode"]
    assert check(None, Request("/s3cret", Headers())) is None and seen[-1] == "/"   # the websocket's path
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and not is_loopback("0.0.0.0")


def test_markers_merge_by_namespace_with_their_colours():
    from geometry_msgs.msg import Point
    from perch_console.scene import merged_groups, triangle_mesh
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker

    def lines(marker_id, x):
        m = Marker(type=Marker.LINE_LIST, ns="surfaces", id=marker_id, action=Marker.ADD,
                   color=ColorRGBA(r=1.0, g=0.0, b=0.0, a=1.0))
        m.pose.orientation.w = 1.0
        m.points = [Point(x=x), Point(x=x, y=1.0)]
        return m

    groups = merged_groups([lines(1, 0.0), lines(2, 2.0), Marker(action=Marker.DELETEALL)])
    [(key, group)] = groups.items()
    assert key == ("surfaces", Marker.LINE_LIST) and np.vstack(group["points"]).shape == (4, 3)
    assert np.vstack(group["colors"])[:, 0].tolist() == [255] * 4
    tri = Marker(type=Marker.TRIANGLE_LIST, ns="scan", action=Marker.ADD)
    tri.pose.orientation.w, tri.pose.position.z = 1.0, 1.0
    tri.points = [Point(x=0.0), Point(x=1.0), Point(y=1.0)]
    tri.colors = [ColorRGBA(r=0.0, g=1.0, b=0.0, a=1.0)] * 3
    mesh = triangle_mesh(tri)
    assert mesh.faces.tolist() == [[0, 1, 2]] and np.allclose(mesh.vertices[:, 2], 1.0)   # pose applied
    assert mesh.visual.vertex_colors[0, :3].tolist() == [0, 255, 0]


def test_a_served_console_answers_only_under_its_token():
    """The gate in front of a real viser server (loopback): the page and its websocket need the token."""
    import urllib.error
    import urllib.request

    import websockets.asyncio.server as ws_server
    from perch_console.cli import require_token
    from perch_console.ui import Console

    original = ws_server.serve
    try:
        require_token("t0ken")
        console = Console(host="127.0.0.1", port=0)
    finally:
        ws_server.serve = original   # the server already bound with the gate; later servers are ungated
    try:
        base = f"http://127.0.0.1:{console.server.get_port()}"
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(base + "/", timeout=30)
        assert refused.value.code == 403 and b"token" in refused.value.read()
        with urllib.request.urlopen(base + "/t0ken/", timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read()[:200].lower()
    finally:
        console.server.stop()


def test_the_console_reads_its_scan_with_the_commands_scale_and_shift(tmp_path):
    from perch_console.ui import scan_source

    path = tmp_path / "site.obj"   # a 4 m x 3 m room in millimetres, in UTM coordinates
    corners = (np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]]) + [450000, 5200000, 300]) * 1000
    path.write_text("".join(f"v {x:.0f} {y:.0f} {z:.0f}\n" for x, y, z in corners) + "f 1 2 3\nf 1 3 4\n")
    mesh, message, _ = scan_source(path, 0.001, (-450000.0, -5200000.0, -300.0))
    assert np.allclose(mesh.vertices, [[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]])
    assert np.allclose(np.reshape(message.vertices, (-1, 3)), mesh.vertices)
