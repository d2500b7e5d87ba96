"""A reconstruction carries the cameras' viewpoints in the cleaned mesh's (gravity-aligned) frame; the
clean stage keeps and turns them; space the camera turned away from is not observed free."""

from __future__ import annotations

import numpy as np

from perch_common.raycast import RayScene
from perch_common.viewpoints import AXIS, CENTRE, HALF_ANGLE, MAX_VIEWPOINTS, RANGE, seen_free
from perch_reconstruction.cleaning import clean_mesh_with_report
from perch_reconstruction.core import ReconstructionConfig, reconstruct_frames


def test_reconstruction_keeps_its_cameras_viewpoints(synthetic):
    scene, frames, intrinsics = synthetic
    config = ReconstructionConfig()
    mesh, stats = reconstruct_frames(frames, intrinsics, config, use_poses=True, gravity=np.array([0.0, 0.0, -1.0]))
    views = mesh.viewpoints
    assert views is not None and 2 <= len(views) <= min(MAX_VIEWPOINTS, len(frames))
    # In the cleaned mesh's frame: the recorded camera centres and axes turned by the cleaning's rotation.
    poses = np.array([pose for _, pose in stats.trajectory])
    rotation = stats.clean.rotation
    centres, axes = poses[:, :3, 3] @ rotation.T, poses[:, :3, 2] @ rotation.T
    for view in views:
        i = np.argmin(np.linalg.norm(centres - view[CENTRE], axis=1) + np.linalg.norm(axes - view[AXIS], axis=1))
        np.testing.assert_allclose(view[CENTRE], centres[i], atol=1e-9)
        np.testing.assert_allclose(view[AXIS], axes[i], atol=1e-9)
    np.testing.assert_allclose(views[:, RANGE], config.depth_max)
    half = np.degrees(min(np.arctan(intrinsics.width / 2 / intrinsics.fx), np.arctan(intrinsics.height / 2 / intrinsics.fy)))
    np.testing.assert_allclose(views[:, HALF_ANGLE], half)
    # The camera turned half a circle: of points 1 m around the trajectory's centre at its height, those it
    # looked towards are observed free, those behind it are not.
    centre = centres.mean(axis=0)
    mean_axis = axes.mean(axis=0)
    mean_axis[2] = 0
    mean_axis /= np.linalg.norm(mean_axis)
    seen = seen_free(RayScene(mesh), views, np.array([centre + mean_axis, centre - mean_axis]))
    np.testing.assert_array_equal(seen, [True, False])
    # Cleaning again (the clean stage) keeps them and turns them with the mesh.
    tilt = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # the mesh given with +y up
    turned = mesh.transformed(np.block([[tilt, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    again, report = clean_mesh_with_report(turned, np.array([0.0, -1.0, 0.0]), config)
    back = report.rotation @ tilt
    np.testing.assert_allclose(again.viewpoints[:, CENTRE], views[:, CENTRE] @ back.T, atol=1e-9)
    np.testing.assert_allclose(again.viewpoints[:, AXIS], views[:, AXIS] @ back.T, atol=1e-9)
