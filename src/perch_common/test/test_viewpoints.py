"""Camera viewpoints travel with a mesh: message round trip, content id, the mesh cache, crop
(submesh) and frame changes; their observed-free space turns with them; bad ones get a clear error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perch_common.mesh import Mesh, MeshError
from perch_common.mesh_cache import PROCESS_CACHE, content_id, mesh_content_id
from perch_common.raycast import RayScene
from perch_common.ros.conversions import id_only_msg, mesh_from_msg, mesh_from_request, mesh_to_msg
from perch_common.scene_generator import generate_scene
from perch_common.viewpoints import AXIS, CENTRE, seen_free, select_viewpoints, viewpoint_rows


def _room_with_views() -> Mesh:
    mesh = generate_scene(3, "room", resolution=0.2).mesh
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2
    yaws = np.radians(np.arange(0, 180, 30))  # half a turn: the other half of the room is unseen
    axes = np.column_stack([np.cos(yaws), np.sin(yaws), np.zeros_like(yaws)])
    mesh.viewpoints = viewpoint_rows(np.repeat(centre[None], len(yaws), axis=0), axes, 6.0, 25.0)
    return mesh


def test_distinct_views_are_kept_and_bounded():
    centres = np.zeros((50, 3))
    centres[:, 0] = np.arange(50) * 0.01           # 1 cm steps, one direction: 0.15 m apart are new
    rows = viewpoint_rows(centres, np.tile([1.0, 0, 0], (50, 1)), 4.0, 30.0)
    kept = select_viewpoints(rows)
    np.testing.assert_allclose(kept[:, 0], [0.0, 0.15, 0.30, 0.45])
    turned = viewpoint_rows(np.zeros((12, 3)), [[np.cos(a), np.sin(a), 0] for a in np.radians(np.arange(12) * 30)],
                            4.0, 30.0)
    assert len(select_viewpoints(turned)) == 12      # the same place, 30 deg apart: all new
    assert len(select_viewpoints(turned, limit=5)) == 5


def test_viewpoints_survive_message_round_trip_cache_and_crop():
    mesh = _room_with_views()
    bare = Mesh(mesh.vertices, mesh.faces)
    msg = mesh_to_msg(mesh)
    assert len(msg.viewpoints) == mesh.viewpoints.size
    back = mesh_from_msg(msg)
    np.testing.assert_array_equal(back.viewpoints, mesh.viewpoints)
    # The content id covers them; a bare mesh keeps the id it had before viewpoints existed.
    assert mesh_content_id(mesh) != mesh_content_id(bare)
    assert mesh_content_id(bare) == content_id(bare.vertices, bare.faces)
    # Cache: sent once with arrays, then by id alone, the held mesh has them.
    PROCESS_CACHE.clear()
    first = mesh_from_request(mesh_to_msg(mesh), "test mesh")
    msg = mesh_to_msg(mesh)
    msg.content_id = mesh_content_id(mesh)
    held = mesh_from_request(id_only_msg(msg), "test mesh")
    np.testing.assert_array_equal(held.viewpoints, mesh.viewpoints)
    assert first.viewpoints is not None and not first.viewpoints.flags.writeable   # shared: read-only
    # Crop: a part of the mesh was observed from the same cameras.
    part = mesh.submesh(mesh.face_centroids()[:, 2] < 1.0)
    assert part.num_faces < mesh.num_faces
    np.testing.assert_array_equal(part.viewpoints, mesh.viewpoints)


def test_a_frame_change_turns_the_viewpoints_and_what_they_observed():
    mesh = _room_with_views()
    transform = np.eye(4)
    transform[:3, :3] = Rotation.from_rotvec(np.radians(70) * np.array([0.95, 0.285, 0.19])).as_matrix()
    transform[:3, 3] = [2.0, -1.0, 0.5]
    moved = mesh.transformed(transform)
    np.testing.assert_allclose(moved.viewpoints[:, CENTRE], mesh.viewpoints[:, CENTRE] @ transform[:3, :3].T
                               + transform[:3, 3], atol=1e-12)
    np.testing.assert_allclose(moved.viewpoints[:, AXIS], mesh.viewpoints[:, AXIS] @ transform[:3, :3].T, atol=1e-12)
    lo, hi = mesh.bounds()
    points = np.random.default_rng(0).uniform(lo + 0.3, hi - 0.3, (400, 3))
    seen = seen_free(RayScene(mesh), mesh.viewpoints, points)
    assert 0.2 < seen.mean() < 0.8   # half the room was looked at
    seen_moved = seen_free(RayScene(moved), moved.viewpoints, points @ transform[:3, :3].T + transform[:3, 3])
    assert (seen != seen_moved).mean() < 0.01   # the same answer in the new frame (float32 rays at edges)


@pytest.mark.parametrize("flat, words", [
    (np.ones(7), "not a multiple of 8"),
    (np.array([0, 0, 0, 1, 0, 0, 4, np.nan]), "NaN"),
    (np.array([0, 0, 0, 2, 0, 0, 4, 30.0]), "unit vector"),
    (np.array([0, 0, 0, 1, 0, 0, 0, 30.0]), "range must be > 0"),
])
def test_bad_viewpoints_are_refused_with_the_problem(flat, words):
    msg = mesh_to_msg(Mesh(np.eye(3), [[0, 1, 2]]))
    msg.viewpoints = flat.astype(np.float64).tolist()
    with pytest.raises(MeshError, match=words):
        mesh_from_msg(msg, "environment mesh")


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_viewpoints_beside_a_mesh_file_load_with_that_geometry_only(tmp_path, suffix):
    from perch_common.mesh import load_mesh, save_mesh
    from perch_common.viewpoints import sidecar_path, write_viewpoints_beside

    mesh = _room_with_views()
    path = save_mesh(tmp_path / f"room{suffix}", mesh)
    assert load_mesh(path).viewpoints is None          # a mesh file alone holds none
    write_viewpoints_beside(path, mesh.vertices, mesh.faces, mesh.viewpoints)
    assert sidecar_path(path).name == f"room{suffix}.viewpoints.json"
    np.testing.assert_allclose(load_mesh(path).viewpoints, mesh.viewpoints)
    in_mm = load_mesh(path, scale=1000.0).viewpoints   # centres and ranges scale with the coordinates
    np.testing.assert_allclose(in_mm[:, CENTRE], 1000.0 * mesh.viewpoints[:, CENTRE])
    np.testing.assert_allclose(in_mm[:, AXIS], mesh.viewpoints[:, AXIS])
    # The file replaced by other geometry (the sidecar left behind): loaded bare, not with stale cameras.
    save_mesh(path, Mesh(mesh.vertices + [0.5, 0, 0], mesh.faces))
    assert load_mesh(path).viewpoints is None
    save_mesh(path, mesh.submesh(np.arange(mesh.num_faces // 2)))
    assert load_mesh(path).viewpoints is None
