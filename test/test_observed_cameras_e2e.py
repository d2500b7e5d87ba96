"""End to end on the real 7-Scenes redkitchen frames: the bag's reconstruction carries its cameras'
viewpoints through the graph (the reconstruct reply's mesh, the later stages by its id), and every
placed perch reports the share of its approach and fall volumes the cameras observed free.

The kitchen scan is 2 m tall and partial: with the default 0.5 m recovery height no perch survives
(filter: recovery_height), before and after the camera rule. The mission runs with 0.3 m so that perches
are placed and their observed share is reported."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

pytestmark = pytest.mark.ros

CAMERAS = 3


@pytest.fixture(scope="module")
def kitchen_bag(tmp_path_factory):
    from perch_common.data import shared_data_dir

    root = shared_data_dir()
    frames = root / "rgbd" / "7scenes-redkitchen" if root else None
    if frames is None or not (frames / "camera-intrinsics.txt").is_file():
        pytest.skip("../shared/data not found: the real 7-Scenes frames (rgbd/7scenes-redkitchen) are absent")
    bag = tmp_path_factory.mktemp("kitchen") / "kitchen.mcap"
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "from-frames", str(frames), "-o", str(bag),
                           "--compressed"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return bag


def reconstructed_viewpoints(recording) -> list[int]:
    """Viewpoints (count) of every mesh the reconstruct service replied with in the recording."""
    from mcap.reader import make_reader

    from perch_common.ros.msgdefs import message_reader

    counts = []
    with open(recording, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=["/perch/reconstruct/_service_event"]):
            event = message_reader(schema.name, schema.data.decode())(message.data)
            counts.extend(len(reply.mesh.viewpoints) // 8 for reply in event.response)
    return counts


def test_kitchen_perches_report_what_the_cameras_observed(kitchen_bag, tmp_path, graph_parts):
    from perch_common.ros import testing

    if graph_parts.missing:
        pytest.skip(f"stage node(s) not installed yet: {', '.join(graph_parts.missing)}")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "plan", "--bag", str(kitchen_bag), "--cameras",
                           str(CAMERAS), "--auto-accept", "-p", "perch_filtering:min_recovery_height:=0.3", "-o", str(out)],
                          capture_output=True, text=True, env=testing.isolated_ros_env(), timeout=1200)
    text = done.stdout + done.stderr
    # The kitchen holds one marginal perch at most, and the reconstruction of the same bag differs by
    # up to 4 cm between runs (not bit-reproducible): a run may find none, and must then say why.
    placed = done.returncode == 0
    assert placed or "filter left no perch regions" in text, text[-3000:]
    views = reconstructed_viewpoints(out / "run.mcap")
    assert views and min(views) >= 10, views   # the cameras' distinct views travelled with the mesh
    if not placed:
        print("no perch this run (the filter's reasons):", text[-600:])
        return
    perches = re.findall(r"drone (\d+) .*observed (\d+) %", text)
    assert perches, text[-3000:]
    shares = {int(drone): int(share) for drone, share in perches}
    print("observed share per placed perch (camera rule):", shares)
    # Every placed perch passed the rule: at most max_unobserved_share (20 %) of either volume unobserved.
    assert all(share >= 80 for share in shares.values()), shares
