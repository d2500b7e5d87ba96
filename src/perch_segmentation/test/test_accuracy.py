"""Accuracy against the procedural scenes' ground truth and on the real apartment scan."""

import numpy as np
import pytest

from perch_common.data import shared_file
from perch_common.scene_generator import SemanticClass, generate_scene
from perch_segmentation.core import SegmentationConfig, segment_mesh
from perch_segmentation.evaluation import score_scene, unite_boundary_planes

CASES = [(kind, noise, holes) for kind in ("room", "l_shaped", "two_rooms", "apartment")
         for noise, holes in ((0.0, 0), (0.005, 4))]


@pytest.mark.parametrize("kind, noise, holes", CASES)
def test_plane_recall_precision_and_normals_on_scenes(kind, noise, holes):
    scene = generate_scene(0, kind, noise=noise, holes=holes)
    scores = score_scene(scene, segment_mesh(scene.mesh, SegmentationConfig()))
    assert scores.ground_truth_planes >= 15
    assert scores.plane_recall >= 0.95, scores
    assert scores.plane_precision >= 0.9, scores
    assert scores.normal_error_deg <= 2.0, scores


def _openings(scene):
    return [p for p in scene.planes if p.semantic_class in (SemanticClass.DOOR, SemanticClass.WINDOW)
            and p.area >= 0.5]


@pytest.mark.parametrize("seed", [0, 1])
def test_flush_doors_and_windows_split_by_colour_only(seed):
    scene = generate_scene(seed, "two_rooms", noise=0.003)
    openings = _openings(scene)
    assert len(openings) >= 2
    areas = scene.mesh.face_areas()
    with_colour = segment_mesh(scene.mesh, SegmentationConfig(use_color=True))
    without = segment_mesh(scene.mesh, SegmentationConfig(use_color=False))
    for plane in openings:
        faces = scene.face_plane == plane.id
        # With colour: one surface holds the opening and little else (IoU >= 0.75).
        labels, counts = np.unique(with_colour.face_labels[faces], return_counts=True)
        own = labels[np.argmax(counts)]
        assert own >= 0
        mine = with_colour.face_labels == own
        iou = areas[faces & mine].sum() / areas[faces | mine].sum()
        assert iou >= 0.75, (plane.semantic_class.name, iou)
        # Without colour: the opening is part of a surface that is mostly wall.
        labels, counts = np.unique(without.face_labels[faces], return_counts=True)
        host = without.face_labels == labels[np.argmax(counts)]
        assert areas[faces & host].sum() >= 0.9 * plane.area
        wall_area = areas[host & (scene.face_class == SemanticClass.WALL)].sum()
        assert wall_area >= 2.0 * plane.area


def test_scene_scoring_counts_misses():
    """The metric itself: a segmentation that merges everything matches nothing."""
    scene = generate_scene(0, "room")
    result = segment_mesh(scene.mesh, SegmentationConfig())
    result.face_labels[:] = 0
    scores = score_scene(scene, result)
    assert scores.plane_recall < 0.1 and scores.plane_precision == 0.0
    united = unite_boundary_planes(scene.face_plane, scene.planes)
    assert len(np.unique(united)) <= len(np.unique(scene.face_plane))


@pytest.mark.data
def test_real_apartment_comes_out_as_few_large_surfaces():
    path = shared_file("meshes", "apartment.ply")
    if path is None:
        pytest.skip("../shared/data not found: meshes/apartment.ply")
    from perch_common.mesh import load_mesh

    mesh = load_mesh(path)
    result = segment_mesh(mesh, SegmentationConfig())
    total = mesh.face_areas().sum()
    top10 = sum(s.area for s in result.surfaces[:10])
    assert top10 >= 0.5 * total
    normals = np.array([s.frame.normal for s in result.surfaces[:5]])
    assert (normals[:, 2] > 0.95).any() and (normals[:, 2] < -0.95).any()  # floor and ceiling among them
    assert (np.abs(normals[:, 2]) < 0.2).sum() >= 2  # and walls
