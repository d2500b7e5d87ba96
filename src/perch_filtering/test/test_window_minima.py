"""raster.erode's minima of a disc taken level by level equal OpenCV's erosion by the whole disc."""

import numpy as np
import pytest

from perch_common.mesh_samples import mesh_samples
from perch_common.scene_generator import generate_scene
from perch_filtering.checks import geometry_in_front
from perch_filtering.raster import rasterise
from perch_filtering.sampling import SampleIndex
from perch_filtering.voxels import grid_rotation


@pytest.fixture(scope="module")
def room():
    return generate_scene(3, "two_rooms")


@pytest.mark.parametrize("radius", [0.0, 2.5, 8.4, 17.7, 25.46])
def test_disc_erosion_by_levels_equals_opencv(radius, monkeypatch):
    """raster.erode takes a disc's minima level by level (from 64 cells a level; forced here for every
    disc): the minima of cv2.erode on scattered float32 depths with a replicated border and on uint8
    masks with a constant one, up to the images' borders and on images narrower than the disc."""
    import cv2

    from perch_filtering import raster
    from perch_filtering.raster import centred_runs, disc_kernel, erode

    monkeypatch.setattr(raster, "RUN_CELLS", 0)
    rng = np.random.default_rng(int(radius * 10))
    kernel = disc_kernel(radius)
    assert centred_runs(kernel) is not None
    for shape in [(7, 5), (60, 140), (333, 251)]:
        depth = np.full(shape, 1.05, np.float32)
        spots = rng.random(shape) < 0.01
        depth[spots] = rng.uniform(0.0, 1.0, int(spots.sum()))
        np.testing.assert_array_equal(erode(depth, kernel, cv2.BORDER_REPLICATE),
                                      cv2.erode(depth, kernel, borderType=cv2.BORDER_REPLICATE))
        alive = (rng.random(shape) < 0.999).astype(np.uint8)
        np.testing.assert_array_equal(erode(alive, kernel, cv2.BORDER_CONSTANT, 0),
                                      cv2.erode(alive, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0))


def test_kernels_that_are_not_discs_are_left_to_opencv():
    from perch_filtering.raster import centred_runs, disc_kernel, turned_kernel, window_kernel

    assert centred_runs(window_kernel(0.5, 0.5, 0.02, False)) == [(12, 12)]  # a rectangle: one level
    assert len(centred_runs(disc_kernel(25.46))) == 15
    assert centred_runs(turned_kernel(window_kernel(0.5, 0.3, 0.02, False), np.radians(30))) is None
    assert centred_runs(np.ones((4, 5), np.uint8)) is None


def test_ceiling_approach_and_fall_equal_opencv_erosions(room, monkeypatch):
    """The any-yaw approach clearance and fall column of the rooms' ceilings (discs of 0.5 m and 0.15 m)
    are those of cv2.erode."""
    import cv2

    from perch_common.types import SurfaceClass
    from perch_filtering import checks
    from perch_filtering.checks import approach_clearance, free_fall

    samples = mesh_samples(room.mesh, 0.05)
    index = SampleIndex(samples, grid_rotation(room.up))
    ceilings = [s for s in room.ground_truth_surfaces() if float(s.frame.normal @ room.up) < -0.9]
    assert ceilings
    for s in ceilings:
        raster = rasterise(s.frame, s.boundary, 0.02, 30, 4_000_000)
        near = geometry_in_front(samples, index, raster, s.face_indices, room.up, 0.03, 1.05, 1.1, 0.05)
        fast = (approach_clearance(raster, near, 0.35, 0.35, 1.0, 0.05, any_yaw=True),
                free_fall(raster, near, room.up, 0.0, 1.0, 0.14, 0.7, 0.05, SurfaceClass.CEILING, any_yaw=True))
        monkeypatch.setattr(checks, "erode", lambda image, kernel, border, value=None: cv2.erode(
            image, kernel, borderType=border))
        plain = (approach_clearance(raster, near, 0.35, 0.35, 1.0, 0.05, any_yaw=True),
                 free_fall(raster, near, room.up, 0.0, 1.0, 0.14, 0.7, 0.05, SurfaceClass.CEILING, any_yaw=True))
        monkeypatch.undo()
        for a, b in zip(fast, plain):
            np.testing.assert_array_equal(a, b)
        assert fast[0].min() < fast[0].max()  # geometry blocks some prisms more than others
