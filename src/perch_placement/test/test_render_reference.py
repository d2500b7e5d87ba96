"""The simulated views are what the plain float64 renderer drew (the fast one shares per-face colours,
shades in float32 and rotates rays without BLAS), to a level of rounding."""

import numpy as np
import pytest

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.scene_generator import generate_scene
from perch_common.transforms import optical_pose_looking_at
from perch_common.types import CameraPlacement
from perch_placement.config import CameraSpec
from perch_placement.render import pixel_rays, render_view, rotate_directions


def reference_view(mesh: Mesh, placement: CameraPlacement, camera: CameraSpec, scale: float):
    """The renderer as it was (float64 throughout, the hit faces' colours averaged per view)."""
    width, height = int(round(camera.width * scale)), int(round(camera.height * scale))
    pose = np.asarray(placement.camera_pose, np.float64)
    world_dirs = pixel_rays(camera, width, height, max(placement.zoom, 1.0)).reshape(-1, 3) @ pose[:3, :3].T
    hits = RayScene(mesh).cast(np.repeat(pose[:3, 3][None], len(world_dirs), axis=0), world_dirs)
    hit = hits.hit & np.isfinite(hits.distance)
    depth = np.where(hit, hits.distance, 0.0).astype(np.float32).reshape(height, width)
    out = np.zeros((len(world_dirs), 3))
    albedo = mesh.face_colors(hits.face[hit])
    albedo = np.full((int(hit.sum()), 3), 0.75) if albedo is None else albedo
    unit = world_dirs[hit] / np.linalg.norm(world_dirs[hit], axis=1, keepdims=True)
    out[hit] = albedo * (0.35 + 0.65 * np.abs((hits.normal[hit] * unit).sum(axis=1)))[:, None]
    return np.clip(out * 255, 0, 255).astype(np.uint8).reshape(height, width, 3), depth


@pytest.fixture(scope="module")
def scene():
    return generate_scene(1, "room", noise=0.005)


def placements(scene) -> list[CameraPlacement]:
    lo, hi = scene.mesh.bounds()
    centre = scene.target.centroid()
    corners = [(0.2, 0.2), (0.8, 0.3), (0.5, 0.8)]
    out = []
    for i, (fx, fy) in enumerate(corners):
        position = np.array([lo[0] + fx * (hi[0] - lo[0]), lo[1] + fy * (hi[1] - lo[1]), hi[2] - 0.4])
        pose = optical_pose_looking_at(position, centre)
        out.append(CameraPlacement(i, 0, pose.copy(), pose, 0.0, 0.0, zoom=1.0 + 0.5 * i))
    return out


def assert_same_view(fast, fast_depth, reference, reference_depth):
    assert fast.shape == reference.shape and fast.dtype == np.uint8
    differs = np.abs(fast.astype(int) - reference.astype(int)).max(axis=-1)
    # Float32 shading moves a level by at most 1; a ray grazing a triangle edge may hit its
    # neighbour after the rounding of its direction: a few pixels in a hundred thousand.
    assert np.mean(differs > 1) < 1e-3
    assert np.mean(differs > 0) < 1e-3
    both = (fast_depth > 0) & (reference_depth > 0)
    assert np.mean((fast_depth > 0) != (reference_depth > 0)) < 1e-3
    assert np.mean(np.abs(fast_depth[both] - reference_depth[both]) < 1e-3) > 0.999


def test_views_are_the_float64_renderers(scene):
    camera = CameraSpec()
    for placement in placements(scene):
        fast, depth = render_view(scene.mesh, placement, camera, None, scale=0.25)
        assert (fast > 0).any(axis=-1).mean() > 0.9   # a room seen from inside: hardly any sky
        assert_same_view(fast, depth, *reference_view(scene.mesh, placement, camera, 0.25))


def test_a_mesh_without_colours_is_shaded_grey_as_before(scene):
    grey = Mesh(scene.mesh.vertices, scene.mesh.faces)
    camera = CameraSpec()
    placement = placements(scene)[0]
    fast, depth = render_view(grey, placement, camera, None, scale=0.25)
    assert (fast[..., 0] == fast[..., 1]).all() and (fast[..., 1] == fast[..., 2]).all()
    assert_same_view(fast, depth, *reference_view(grey, placement, camera, 0.25))


def test_face_color_table_is_face_colors_computed_once(scene):
    mesh = Mesh(scene.mesh.vertices, scene.mesh.faces, scene.mesh.vertex_colors)
    table = mesh.face_color_table()
    assert table.dtype == np.float32 and table.shape == (mesh.num_faces, 3)
    assert np.allclose(table, mesh.face_colors(), atol=1e-6)
    assert mesh.face_color_table() is table and not table.flags.writeable   # kept, shared, read-only
    assert Mesh(mesh.vertices, mesh.faces).face_color_table() is None


def test_rotate_directions_is_the_matrix_product():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(1000, 3))
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rotated = rotate_directions(directions, rotation)
    assert rotated.dtype == np.float32
    assert np.allclose(rotated, directions @ rotation.T, atol=1e-6)
