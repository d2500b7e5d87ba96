"""Shared fixtures: synthetic RGB-D frames of a generated room, the real 7-Scenes frames when present."""

from __future__ import annotations

import numpy as np
import pytest

from perch_reconstruction.synthetic import DEFAULT_INTRINSICS, synthetic_room_frames

SYNTHETIC_FRAMES = 40


@pytest.fixture(scope="session")
def synthetic():
    """(scene, frames, intrinsics): a generated room seen while turning half a circle."""
    scene, frames = synthetic_room_frames(seed=1, count=SYNTHETIC_FRAMES)
    return scene, frames, DEFAULT_INTRINSICS


@pytest.fixture(scope="session")
def synthetic_bag(synthetic, tmp_path_factory):
    from perch_reconstruction.bag_write import write_bag

    _, frames, intrinsics = synthetic
    path = tmp_path_factory.mktemp("bags") / "synthetic.mcap"
    write_bag(path, frames, intrinsics, gravity=np.array([0.0, 0.0, -1.0]))
    return path


@pytest.fixture(scope="session")
def kitchen_dir():
    from perch_common.data import shared_data_dir

    root = shared_data_dir()
    path = root / "rgbd" / "7scenes-redkitchen" if root else None
    if path is None or not (path / "camera-intrinsics.txt").is_file():
        pytest.skip("../shared/data not found: the real 7-Scenes frames (rgbd/7scenes-redkitchen) are absent")
    return path
