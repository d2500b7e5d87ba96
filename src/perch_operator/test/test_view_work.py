"""The coordinator's view thread never holds an earlier mission's work: when a mission starts, the
views still queued from the one before are dropped (they held its meshes while the views lagged
behind the missions on a loaded machine, and would have drawn an old picture into the new one)."""

from __future__ import annotations

import threading

import pytest

pytestmark = pytest.mark.ros


def test_a_new_mission_drops_the_view_work_still_queued():
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    from perch_operator.coordinator.node import OperatorNode

    rclpy.init()
    try:
        node = OperatorNode()
        busy, release, ran = threading.Event(), threading.Event(), []
        try:
            node._submit_view(lambda: (busy.set(), release.wait(60)))   # the view being drawn now
            assert busy.wait(60)
            for i in range(3):   # queued behind it, each holding its mission's request
                node._submit_view(ran.append, i)
            assert node._drop_earlier_views() == 3
            release.set()
            node._submit_view(ran.append, "next mission")
            node._view_worker.submit(lambda: None).result(60)   # the thread has drained its queue
            assert ran == ["next mission"]
            assert node._drop_earlier_views() == 0   # nothing left queued
        finally:
            release.set()
            node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_the_scan_marker_of_a_given_mesh_leaves_the_stages_cache_alone():
    """A given mesh's scan marker decodes the goal's arrays for the picture only: it neither hashes
    them nor keeps the mesh in the process cache the stages share (a building's 2.3 M faces stayed
    there, with their cross products, until evicted); an id-only mesh is still read from that cache."""
    import numpy as np

    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    from perch_common.mesh import Mesh
    from perch_common.mesh_cache import PROCESS_CACHE
    from perch_common.ros.conversions import cached_mesh_to_msg, id_only_msg, mesh_to_msg, msg_content_id
    from perch_operator.coordinator.node import OperatorNode

    rng = np.random.default_rng(2)
    given = mesh_to_msg(Mesh(rng.random((60, 3)), rng.integers(0, 60, (80, 3))))
    rclpy.init()
    try:
        node = OperatorNode()
        published = []
        node.scan_pub.publish = published.append
        try:
            node._publish_scan(given, np.eye(4), "map")
            assert len(published) == 1 and msg_content_id(given) not in PROCESS_CACHE
            held = cached_mesh_to_msg(Mesh(rng.random((30, 3)), rng.integers(0, 30, (40, 3))))
            node._publish_scan(id_only_msg(held), np.eye(4), "map")
            assert len(published) == 2
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
