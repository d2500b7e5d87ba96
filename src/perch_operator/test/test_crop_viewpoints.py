"""The crop stage keeps the viewpoints a reconstruction's mesh was observed from (its part was observed
from the same cameras), through its service reply as well."""

import numpy as np

from perch_common.ros.conversions import mesh_from_msg, mesh_to_msg
from perch_common.viewpoints import viewpoint_rows
from perch_operator.coordinator.crop import Box, crop_mesh


def test_crop_keeps_the_cameras_viewpoints(meshes):
    mesh = meshes.room()
    mesh.viewpoints = viewpoint_rows([[1.0, 1.5, 1.2], [3.0, 1.5, 1.2]], [[1.0, 0, 0], [-1.0, 0, 0]], 4.0, 30.0)
    result = crop_mesh(mesh, keep_boxes=[Box(center=[1.0, 1.5, 1.25], size=[2.0, 3.2, 3.0])])
    assert 0 < result.mesh.num_faces < mesh.num_faces
    np.testing.assert_array_equal(result.mesh.viewpoints, mesh.viewpoints)
    np.testing.assert_array_equal(mesh_from_msg(mesh_to_msg(result.mesh)).viewpoints, mesh.viewpoints)
