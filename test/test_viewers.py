"""What Foxglove and RViz need to see the room is in a mission's run.mcap and decodes with Foxglove's decoders.

One recorded auto-accept mission on a generated room: the scan marker (a coloured TRIANGLE_LIST within
its budget), the mission's MarkerArray with short labels, each drone's own image and camera-info
topics, and every topic config/foxglove_layout.json and config/perch.rviz name for those drones.
"""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest
import yaml

pytestmark = pytest.mark.ros

CAMERAS = 3
SCENE_SEED = 3


@pytest.fixture(scope="module")
def recorded(graph, tmp_path_factory):
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.runner import run_recorded_mission

    scene = generate_scene(SCENE_SEED, "room")
    goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target), num_cameras=CAMERAS,
                            auto_accept=True, seed=-1)
    outputs = run_recorded_mission(graph.node, goal, tmp_path_factory.mktemp("viewers"), progress=False,
                                   timeout=300)
    assert outputs.result.success, outputs.result.message
    return outputs, scene


def viewer_topics() -> set[str]:
    """The /perch topics the shipped Foxglove layout and RViz config display (drones 0.. CAMERAS-1)."""
    from perch_common.data import repo_root

    config = repo_root() / "config"
    layout = json.dumps(json.loads((config / "foxglove_layout.json").read_text()))
    rviz = yaml.safe_load((config / "perch.rviz").read_text())
    names = set(re.findall(r'"(/perch/[^"]+)"', layout))
    names |= {d["Topic"]["Value"] for d in rviz["Visualization Manager"]["Displays"] if "Topic" in d}
    drones = {int(n) for n in re.findall(r"drone_(\d+)", " ".join(names))}
    assert drones and max(drones) < CAMERAS, "the test mission must have every drone the configs show"
    return {n for n in names if n.startswith("/perch/") and not n.startswith("/perch/confirm")}


def test_rviz_reads_every_latched_topic_transient_local():
    from perch_common.data import repo_root

    rviz = yaml.safe_load((repo_root() / "config" / "perch.rviz").read_text())
    displays = [d for d in rviz["Visualization Manager"]["Displays"] if "Topic" in d]
    assert {d["Class"] for d in displays} >= {"rviz_default_plugins/Marker", "rviz_default_plugins/MarkerArray",
                                              "rviz_default_plugins/Image"}
    assert all(d["Topic"]["Durability Policy"] == "Transient Local" for d in displays)


def test_recording_holds_the_room_and_every_drone_view_a_viewer_shows(recorded):
    from visualization_msgs.msg import Marker

    from perch_operator.coordinator.markers import SCAN_TRIANGLE_BUDGET
    from perch_operator.outputs.runfile import channel_counts, iter_messages

    outputs, scene = recorded
    counts = channel_counts(outputs.mcap)
    missing = viewer_topics() - set(counts)
    assert not missing, f"topics the viewer configs show but run.mcap lacks: {sorted(missing)}"
    [scan] = [m for _, m, _ in iter_messages(outputs.mcap, ["/perch/scan_marker"])]
    assert scan.type == Marker.TRIANGLE_LIST and scan.header.frame_id == "map"
    assert 0 < len(scan.points) // 3 <= SCAN_TRIANGLE_BUDGET and len(scan.colors) == len(scan.points)
    xyz = np.array([(p.x, p.y, p.z) for p in scan.points])
    low, high = scene.mesh.vertices.min(axis=0), scene.mesh.vertices.max(axis=0)
    np.testing.assert_allclose(xyz.min(axis=0), low, atol=0.25)   # the whole room, in the input frame
    np.testing.assert_allclose(xyz.max(axis=0), high, atol=0.25)
    [picture] = [m for _, m, _ in iter_messages(outputs.mcap, ["/perch/markers"])]
    labels = [m.text for m in picture.markers if m.type == Marker.TEXT_VIEW_FACING]
    assert labels and max(len(t) for t in labels) <= 6, labels   # short labels only
    for drone in range(CAMERAS):
        images = [m for _, m, _ in iter_messages(outputs.mcap, [f"/perch/views/drone_{drone}/image"])]
        infos = [m for _, m, _ in iter_messages(outputs.mcap, [f"/perch/views/drone_{drone}/camera_info"])]
        assert len(images) == len(infos) == 1
        assert images[0].header.frame_id == infos[0].header.frame_id == f"perch_drone_{drone}_camera_optical"
        assert (images[0].width, images[0].height) == (infos[0].width, infos[0].height)
        assert np.frombuffer(bytes(images[0].data), np.uint8).std() > 0


def test_viewer_topics_decode_with_foxgloves_own_decoders(recorded):
    from perch_common.bag_check import DecoderUnavailable, foxglove_counts
    from perch_operator.outputs.runfile import channel_counts

    outputs, _ = recorded
    counts = channel_counts(outputs.mcap)
    try:
        decoded = foxglove_counts(outputs.mcap)
    except DecoderUnavailable as exc:
        pytest.skip(f"Foxglove's decoders not run: {exc}")
    wanted = viewer_topics() | {"/perch/scan_marker", "/perch/markers"}
    assert {t: decoded.get(t) for t in wanted} == {t: (counts[t], counts[t]) for t in wanted}


def test_a_viewer_joining_late_gets_the_scan_and_each_drones_view(graph, recorded):
    from sensor_msgs.msg import Image
    from visualization_msgs.msg import Marker

    from perch_operator.cli.runner import spin_for
    from perch_operator.coordinator.node import LATCHED_LAST

    got: dict[str, object] = {}
    node = graph.node
    subs = [node.create_subscription(Marker, "/perch/scan_marker", lambda m: got.setdefault("scan", m), LATCHED_LAST)]
    for drone in range(CAMERAS):
        topic = f"/perch/views/drone_{drone}/image"
        subs.append(node.create_subscription(Image, topic, lambda m, t=topic: got.setdefault(t, m), LATCHED_LAST))
    deadline = time.monotonic() + 120
    while len(got) < CAMERAS + 1 and time.monotonic() < deadline:
        spin_for(node, 0.1)
    for sub in subs:
        node.destroy_subscription(sub)
    assert len(got) == CAMERAS + 1, f"a late viewer got only {sorted(got)}"
