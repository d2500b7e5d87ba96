"""End to end: the world rotated. Missions on rotated copies of a generated room (six orientations,
PLY/OBJ/GLB files) and of the shared real scans answer in the input's own frame: waypoints on the rotated
input mesh, drones on walls and ceilings of the true room, the fitness of the un-rotated mission
with perches on the same surfaces; a contradicted --up fails clearly and the graph keeps serving;
a bag's waypoints come back in the frame of its recorded poses.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

CAMERAS = 3
FORMATS = {"z-up": ".ply", "y-up": ".obj", "y-down": ".glb", "x-up": ".ply", "tilt-25": ".obj", "tilt-35": ".glb"}
ON_MESH_M = 0.02
FITNESS_TOLERANCE = 0.01   # axis-aligned copies reach the stages bit-identical: the same answer
# A tilted real scan reaches the stages within float32 rounding of the original (<1e-6 m), and neither
# segmentation's thresholds nor the placement search are continuous in that rounding: the apartment's
# ceiling surface gains 49 of its 10,338 faces and the answer 7 % fitness; the office's regions agree to
# 1e-5 m and its search (seed 0) still goes elsewhere: 5 % (the search's own spread over seeds 0-7 on the
# office: 4 %). A frame mistake (a lost surface, a misplaced target, a wrong up) is caught by the other
# checks (on the mesh, walls and ceilings only) or costs more than this.
TILTED_REAL_SCAN_FITNESS_TOLERANCE = 0.1


@pytest.fixture(scope="module")
def scene():
    from perch_common.scene_generator import generate_scene

    return generate_scene(3, "room")


def target_in(target, transform: np.ndarray):
    """The scene's target box moved by a 4x4 rotation, as a goal message (input frame)."""
    from perch_common.ros.conversions import target_to_msg
    from perch_common.target import TargetVolume

    assert target.is_box
    r = transform[:3, :3]
    return target_to_msg(TargetVolume(center=r @ target.center, size=target.size, rotation=r @ target.rotation))


def run_mission(graph, goal, tmp_path_factory, name: str):
    from perch_operator.cli.runner import run_recorded_mission

    return run_recorded_mission(graph.node, goal, tmp_path_factory.mktemp(name), progress=False, timeout=300).result


def distances_to(mesh, points: np.ndarray) -> np.ndarray:
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()


def waypoint_poses(result) -> list[np.ndarray]:
    from perch_common.ros.conversions import pose_matrix

    return [pose_matrix(w.pose.pose) for w in sorted(result.waypoints, key=lambda w: w.drone_index)]


def perched_planes(scene, true_positions: np.ndarray) -> set[int]:
    """Ground-truth plane ids under the perches (positions in the scene's own frame)."""
    centroids = scene.mesh.face_centroids()
    return {int(scene.face_plane[np.argmin(np.linalg.norm(centroids - p, axis=1))]) for p in true_positions}


@pytest.fixture(scope="module")
def baseline(graph, scene, tmp_path_factory):
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_interfaces.action import PlanPerches

    goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                            num_cameras=CAMERAS, auto_accept=True, seed=-1)
    result = run_mission(graph, goal, tmp_path_factory, "baseline")
    assert result.success, result.message
    return result


@pytest.mark.parametrize("orientation", list(FORMATS))
def test_rotated_room_mission_answers_in_the_input_frame(graph, scene, baseline, tmp_path_factory, orientation):
    from perch_common.mesh import save_mesh
    from perch_common.ros.static_transforms import alignment_from_msg
    from perch_common.scan_orientations import oriented
    from perch_interfaces.action import PlanPerches

    rotated, true_up, transform = oriented(scene.mesh, np.array([0.0, 0.0, 1.0]), orientation)
    path = save_mesh(tmp_path_factory.mktemp("rotated") / f"room-{orientation}{FORMATS[orientation]}", rotated)
    goal = PlanPerches.Goal(mesh_path=str(path), target=target_in(scene.target, transform), num_cameras=CAMERAS,
                            auto_accept=True, seed=-1)
    result = run_mission(graph, goal, tmp_path_factory, orientation)
    assert result.success, result.message
    assert len(result.waypoints) == len(baseline.waypoints) == CAMERAS
    # The alignment found the true up of the rotated copy.
    alignment = alignment_from_msg(result.alignment)
    assert np.degrees(np.arccos(np.clip(alignment.up @ true_up, -1, 1))) < 3.0
    assert {w.pose.header.frame_id for w in result.waypoints} == {result.alignment.header.frame_id} == {"map"}
    poses = waypoint_poses(result)
    positions = np.array([p[:3, 3] for p in poses])
    assert distances_to(rotated, positions).max() <= ON_MESH_M  # on the rotated input mesh
    # In the true (un-rotated) frame every drone sits on a wall or a ceiling: its z axis (the surface
    # normal) is horizontal or points down, never up.
    true_normals = np.array([transform[:3, :3].T @ p[:3, 2] for p in poses])
    assert (true_normals[:, 2] < 0.3).all(), true_normals
    assert abs(result.fitness - baseline.fitness) <= FITNESS_TOLERANCE * baseline.fitness
    true_positions = positions @ transform[:3, :3]  # each row: R^T p
    base_positions = np.array([p[:3, 3] for p in waypoint_poses(baseline)])
    assert perched_planes(scene, true_positions) == perched_planes(scene, base_positions)


def test_contradicted_up_fails_clearly_and_the_graph_keeps_serving(graph, scene, tmp_path_factory):
    from perch_common.ros.conversions import mesh_to_msg
    from perch_common.scan_orientations import oriented
    from perch_interfaces.action import PlanPerches

    rotated, _, transform = oriented(scene.mesh, np.array([0.0, 0.0, 1.0]), "y-down")
    goal = PlanPerches.Goal(mesh=mesh_to_msg(rotated), target=target_in(scene.target, transform),
                            num_cameras=CAMERAS, auto_accept=True, seed=-1, up_axis="+y")
    failed = run_mission(graph, goal, tmp_path_factory, "contradicted")
    assert not failed.success
    assert failed.message.startswith("--up +y contradicts the mesh: furniture tops face down along it")
    assert failed.message.endswith("pass --up -y (or --up auto)")
    goal.up_axis = "-y"
    again = run_mission(graph, goal, tmp_path_factory, "corrected")
    assert again.success and len(again.waypoints) == CAMERAS, again.message


@pytest.mark.parametrize("scan", ["icl_livingroom_kt2.obj", "icl_office_kt2.obj", "apartment.ply"])
def test_real_scan_rotated_lands_on_its_input_mesh(graph, tmp_path_factory, scan):
    """Each shared real scan as it is and tilted twice."""
    from perch_common.data import shared_file
    from perch_common.mesh import load_mesh, save_mesh
    from perch_common.scan_orientations import REAL_SCANS, oriented
    from perch_interfaces.action import PlanPerches

    path = shared_file("meshes", scan)
    if path is None:
        pytest.skip(f"../shared/data/meshes/{scan} is absent (real scans are optional)")
    mesh = load_mesh(path)
    results = {}
    for orientation in ("native", "tilt-25", "tilt-35"):
        if orientation == "native":  # the file as it is (ICL-NUIM: -y up)
            rotated, source, transform = mesh, path, np.eye(4)
        else:
            rotated, _, transform = oriented(mesh, REAL_SCANS[scan], orientation)
            source = save_mesh(tmp_path_factory.mktemp("real") / f"scan{FORMATS[orientation]}", rotated)
        goal = PlanPerches.Goal(mesh_path=str(source), num_cameras=CAMERAS, auto_accept=True, seed=-1)
        result = run_mission(graph, goal, tmp_path_factory, f"real-{orientation}")
        assert result.success, (orientation, result.message)
        poses = waypoint_poses(result)
        positions = np.array([p[:3, 3] for p in poses])
        assert distances_to(rotated, positions).max() <= ON_MESH_M, orientation
        true_up = transform[:3, :3] @ REAL_SCANS[scan]
        assert all(p[:3, 2] @ true_up < 0.3 for p in poses), orientation  # walls and ceilings only
        results[orientation] = result
    # A tilted copy reaches the stages gravity-aligned, identical to float32 rounding (<1e-6 m) and in
    # the same vertex order: the stages answer the same problem, within the search's sensitivity.
    native = results["native"].fitness
    for orientation in ("tilt-25", "tilt-35"):
        tilted = results[orientation].fitness
        assert abs(tilted - native) <= TILTED_REAL_SCAN_FITNESS_TOLERANCE * native, (orientation, native, tilted)


def test_bag_waypoints_are_in_the_frame_of_its_poses(graph, tmp_path_factory):
    """A synthetic bag whose recorded poses live in a y-down frame 'scan_world': the waypoints come back
    in that frame (named so) and on the room as the bag's cameras saw it."""
    from dataclasses import replace

    from perch_common.scan_orientations import orientation_transform
    from perch_interfaces.action import PlanPerches
    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.synthetic import DEFAULT_INTRINSICS, synthetic_room_frames

    scene, frames = synthetic_room_frames(seed=1, count=40, turn=2 * np.pi)
    transform = orientation_transform(np.array([0.0, 0.0, 1.0]), "y-down")
    moved = [replace(f, pose=transform @ f.pose) for f in frames]
    path = tmp_path_factory.mktemp("bag") / "scan.mcap"
    write_bag(path, moved, DEFAULT_INTRINSICS, world_frame="scan_world")  # no gravity record: estimated
    goal = PlanPerches.Goal(bag_path=str(path), num_cameras=2, auto_accept=True, seed=-1)
    result = run_mission(graph, goal, tmp_path_factory, "bag")
    assert result.success, result.message
    assert result.alignment.header.frame_id == "scan_world"
    assert {w.pose.header.frame_id for w in result.waypoints} == {"scan_world"}
    positions = np.array([p[:3, 3] for p in waypoint_poses(result)])
    room_in_bag_frame = scene.mesh.transformed(transform)
    assert distances_to(room_in_bag_frame, positions).max() <= 0.05  # reconstruction error, voxel-sized
    cameras = np.array([f.pose[:3, 3] for f in moved])
    lo, hi = room_in_bag_frame.bounds()
    assert ((cameras > lo) & (cameras < hi)).all() and ((positions > lo - 0.05) & (positions < hi + 0.05)).all()
