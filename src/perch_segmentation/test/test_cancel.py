"""Segmentation stops at its next step once its request is cancelled."""

from __future__ import annotations

import threading
import time

import pytest

from perch_common.cancellation import Cancelled, CancelToken, cancellable


def test_a_long_segmentation_stops_soon_after_a_cancel():
    """Cancelling from another thread stops segment_mesh at its next step (as the node's subscriber does)."""
    from perch_common.scene_generator import generate_scene
    from perch_segmentation.core import SegmentationConfig, segment_mesh

    mesh = generate_scene(2, "apartment").mesh
    started = time.monotonic()
    segment_mesh(mesh, SegmentationConfig())
    full = time.monotonic() - started
    token = CancelToken()
    threading.Timer(0.05 * full, token.cancel, args=("cancelled by the test",)).start()
    started = time.monotonic()
    with cancellable(token), pytest.raises(Cancelled, match="cancelled by the test"):
        segment_mesh(mesh, SegmentationConfig())
    stopped = time.monotonic() - started
    assert stopped < 0.8 * full, f"stopped after {stopped:.2f} s of a {full:.2f} s segmentation"
