"""Live ingestion without ROS: bounded queue, drop-oldest policy, camera-info timeout, errors kept apart."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.errors import PerchError
from perch_reconstruction.config import ReconstructionNodeConfig
from perch_reconstruction.live import LiveIngest
from perch_reconstruction.progress import MODE_LIVE, NO_CAMERA_INFO, QUEUE_FULL, UNPAIRED


def _feed(ingest: LiveIngest, frames, poses: bool = True) -> None:
    for frame in frames:
        if poses:
            ingest.on_pose(frame.stamp_ns, frame.pose)
        ingest.on_color(frame.stamp_ns, frame.color)
        ingest.on_depth(frame.stamp_ns, frame.depth)


@pytest.fixture
def make_ingest():
    made = []

    def make(**overrides):
        ingest = LiveIngest(ReconstructionNodeConfig(**overrides), log=lambda message: None)
        made.append(ingest)
        return ingest

    yield make
    for ingest in made:
        ingest.stop()


def _integrated(make_ingest, synthetic, count: int, poses: bool = True, **overrides) -> tuple[LiveIngest, list]:
    """An ingest (queue of 50) that has received the camera info and the first `count` frames and
    worked through them; with the synthetic frames."""
    _, frames, intrinsics = synthetic
    ingest = make_ingest(queue_size=50, **overrides)
    ingest.on_camera_info(intrinsics)
    _feed(ingest, frames[:count], poses)
    assert ingest.drain(30)
    return ingest, frames


def test_full_queue_drops_the_oldest_and_counts(synthetic, make_ingest):
    _, frames, intrinsics = synthetic
    ingest = make_ingest(queue_size=1)
    ingest.on_camera_info(intrinsics)
    _feed(ingest, frames[:15])  # far faster than integration
    assert ingest.drain(60)
    status = ingest.status()
    assert status.mode == MODE_LIVE and status.dropped[QUEUE_FULL] >= 5 and status.queued == 0
    assert status.frames_integrated + status.frames_dropped == 15 == status.frames_received + status.frames_dropped
    assert status.frames_dropped == sum(status.dropped.values())
    assert ingest.recon.stats.trajectory[-1][0] == frames[14].stamp_ns  # the newest view always makes it


def test_no_camera_info_reports_topic_and_keeps_running(synthetic, make_ingest):
    _, frames, intrinsics = synthetic
    ingest = make_ingest(camera_info_timeout=0.2, queue_size=50)
    _feed(ingest, frames[:3])
    assert ingest.drain(10)
    assert ingest.status().dropped == {QUEUE_FULL: 0, UNPAIRED: 0, NO_CAMERA_INFO: 3}
    with pytest.raises(PerchError, match=r"no camera info on /camera/depth/camera_info within 0.2 s"):
        ingest.finish(None)
    ingest.on_camera_info(intrinsics)  # the camera info arrives late: integration resumes
    _feed(ingest, frames[3:8])
    assert ingest.drain(30)
    assert ingest.status().frames_integrated == 5


def test_bad_depth_units_are_reported_and_integration_kept(synthetic, make_ingest):
    ingest, frames = _integrated(make_ingest, synthetic, 4)
    bad = frames[4]
    ingest.on_pose(bad.stamp_ns, bad.pose)
    ingest.on_color(bad.stamp_ns, bad.color)
    ingest.on_depth(bad.stamp_ns, bad.depth * 1000)  # millimetres as metres
    assert ingest.drain(30)
    status = ingest.status()
    assert status.frames_integrated == 4
    assert "/camera/depth/image_raw: median depth" in status.last_error
    assert ingest.finish(np.array([0, 0, -1.0]))[0].num_faces > 0


def test_nothing_received(make_ingest):
    ingest = make_ingest()
    with pytest.raises(PerchError, match="no colour\\+depth pairs received on /camera/color/image_raw"):
        ingest.finish(None)


def test_missing_poses_are_counted(synthetic, make_ingest):
    ingest, _ = _integrated(make_ingest, synthetic, 3, poses=False, pose_wait=0.05)
    assert ingest.status().frames_without_pose == 3


def test_reset_clears_everything(synthetic, make_ingest):
    ingest, _ = _integrated(make_ingest, synthetic, 3)
    assert ingest.status().blocks > 0 and ingest.status().frames_integrated == 3
    ingest.reset()
    status = ingest.status()
    assert status.frames_integrated == 0 and status.frames_dropped == 0 and ingest.intrinsics is None
    assert status.blocks == 0 and status.seconds_integrate == 0.0
