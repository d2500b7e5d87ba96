"""The output phase's pictures, made fast, show what they showed: the top view is the culled-submesh
render, the views and the target scores share one ray-cast scene, surfaces go to rerun as
submeshes, and a live mission's views start from the mesh the stages hold."""

import numpy as np
import pytest

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.scene_generator import generate_scene
from perch_common.transforms import optical_pose_looking_at
from perch_common.types import CameraPlacement
from perch_operator.outputs.mission_data import MissionData


@pytest.fixture(scope="module")
def scene():
    return generate_scene(2, "room", noise=0.005)


def reference_top_view(mesh: Mesh, view) -> np.ndarray:
    """The top view as it was drawn: the up-facing faces as a submesh, shaded in float64."""
    visible = np.flatnonzero(mesh.face_normals()[:, 2] > -0.2)
    sub = mesh.submesh(visible)
    xy = view.cell_centres()
    origins = np.column_stack([xy, np.full(len(xy), mesh.bounds()[1, 2] + 1.0)])
    hits = RayScene(sub).cast(origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1)))
    colors = sub.face_colors()
    base = np.full((len(xy), 3), 0.75) if colors is None else np.zeros((len(xy), 3))
    if colors is not None:
        base[hits.hit] = colors[hits.face[hits.hit]]
    light = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    shade = 0.45 + 0.55 * np.abs(hits.normal @ light)
    rgb = np.where(hits.hit[:, None], base * shade[:, None], 1.0)
    image = (np.clip(rgb, 0, 1) * 255).astype(np.uint8).reshape(view.height, view.width, 3)
    return image[:, :, ::-1]


@pytest.mark.parametrize("coloured", [True, False])
def test_top_view_is_the_culled_submesh_render(scene, coloured):
    from perch_operator.outputs.render import TopView, shaded_top_view

    mesh = scene.mesh if coloured else Mesh(scene.mesh.vertices, scene.mesh.faces)
    view = TopView(mesh.bounds(), 300)
    fast, reference = shaded_top_view(mesh, view), reference_top_view(mesh, view)
    assert fast.shape == reference.shape == (view.height, view.width, 3) and fast.dtype == np.uint8
    differs = np.abs(fast.astype(int) - reference.astype(int)).max(axis=-1)
    assert differs.max() <= 1 and np.mean(differs > 0) < 1e-3   # float32 shading: a level at most
    assert (fast == 255).all(axis=-1).mean() < 0.5                # the floor is drawn, not left white


def test_target_edges_drawn_as_one_polyline_call_are_the_lines_drawn_one_by_one():
    """overview draws the target's edges with one cv2.polylines call instead of a cv2.line per edge."""
    import cv2

    rng = np.random.default_rng(1)
    ends = np.round(rng.uniform(0, 200, (300, 2, 2))).astype(np.int32)
    one_by_one, at_once = np.full((200, 200, 3), 255, np.uint8), np.full((200, 200, 3), 255, np.uint8)
    for a, b in ends:
        cv2.line(one_by_one, tuple(map(int, a)), tuple(map(int, b)), (0, 140, 255), 2, cv2.LINE_AA)
    cv2.polylines(at_once, list(ends.reshape(-1, 2, 1, 2)), False, (0, 140, 255), 2, cv2.LINE_AA)
    assert np.array_equal(one_by_one, at_once)



def scene_mission(scene) -> MissionData:
    lo, hi = scene.mesh.bounds()
    centre = scene.target.centroid()
    placements = []
    for i, (fx, fy) in enumerate([(0.2, 0.2), (0.8, 0.7)]):
        position = np.array([lo[0] + fx * (hi[0] - lo[0]), lo[1] + fy * (hi[1] - lo[1]), hi[2] - 0.4])
        pose = optical_pose_looking_at(position, centre)
        placements.append(CameraPlacement(i, 0, pose.copy(), pose, 0.0, 0.0))
    mesh = Mesh(scene.mesh.vertices, scene.mesh.faces, scene.mesh.vertex_colors)   # nothing derived yet
    return MissionData(mesh=mesh, cropped=mesh, target=scene.target, placements=placements)


def test_views_and_target_scores_share_one_scene(scene, monkeypatch):
    import perch_common.raycast
    from perch_operator.outputs.mission_data import placement_config, target_point_scores
    from perch_operator.outputs.render import camera_views

    built = []

    class CountedScene(RayScene):
        def __init__(self, mesh):
            built.append(mesh)
            super().__init__(mesh)

    monkeypatch.setattr(perch_common.raycast, "RayScene", CountedScene)
    data = scene_mission(scene)
    views = camera_views(data)
    points, scores = target_point_scores(data)
    camera = placement_config().camera
    assert len(views) == 2 and all(v.shape == (round(camera.height / 2), round(camera.width / 2), 3) for v in views)
    assert scores.shape == (len(points),) and scores.max() > 0
    assert built == [data.mesh]   # one BVH for both views and the scores


def test_a_live_missions_mesh_is_the_one_the_stages_hold(scene, monkeypatch):
    """After a one-process mission the recorded mesh is the held one (with what the stages derived
    from it), but only when the recording's arrays are what its content id names."""
    import perch_common.mesh_cache
    from perch_common.mesh_cache import MeshCache
    from perch_common.ros.conversions import cached_mesh_to_msg, held_mesh, mesh_to_msg

    monkeypatch.setattr(perch_common.mesh_cache, "PROCESS_CACHE", MeshCache(10**9))
    msg = cached_mesh_to_msg(scene.mesh)   # as a stage's reply: kept under its content id
    held = perch_common.mesh_cache.PROCESS_CACHE.get(msg.content_id)
    held.face_normals()                    # per-face data a stage derived
    mesh = held_mesh(msg)
    assert mesh is not held and mesh._cache is held._cache and mesh.vertices is held.vertices
    assert "cross" in mesh._cache
    other = mesh_to_msg(Mesh(scene.mesh.vertices + 1.0, scene.mesh.faces))
    other.content_id = msg.content_id      # a recording whose arrays are not what its id names
    assert held_mesh(other) is None
    assert held_mesh(mesh_to_msg(scene.mesh)) is None   # no content id
    perch_common.mesh_cache.PROCESS_CACHE.clear()
    assert held_mesh(msg) is None          # not held (a recording read in another process)
