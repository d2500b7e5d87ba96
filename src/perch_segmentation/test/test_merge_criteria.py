"""Each merge rule on its own: step 2 criteria, floor/ceiling union, step 1 energy and folds, fragments."""

import math

import numpy as np
import pytest

from perch_segmentation import stats as st
from perch_segmentation.agglomerate import MergeRules, grow_clusters
from perch_segmentation.fragments import absorb_fragments
from perch_segmentation.merge_pass import (
    Geometry,
    PlaneRules,
    boundary_plane_groups,
    colors_close,
    merge_coplanar,
    normals_agree,
    planes_close,
    side_by_side,
)
from perch_segmentation.testing import grid_rect, weld

RULES = PlaneRules(theta_max_deg=15.0, theta_min_deg=70.0, d_max=0.2, color_threshold=20.0)
PAIR = (np.array([0]), np.array([1]))


def geometry(centroids, normals, labs=((50, 0, 0), (50, 0, 0)), areas=(1.0, 1.0)):
    normals = np.asarray(normals, float)
    return Geometry(np.asarray(areas, float), np.asarray(centroids, float),
                    normals / np.linalg.norm(normals, axis=1, keepdims=True), np.asarray(labs, float))


def tilted(deg):
    return [0.0, np.sin(np.radians(deg)), np.cos(np.radians(deg))]


@pytest.mark.parametrize("deg, expected", [(0, True), (14.0, True), (16.0, False), (90, False), (180, True)])
def test_normals_agree_below_theta_max(deg, expected):
    g = geometry([[0, 0, 0], [1, 0, 0]], [[0, 0, 1], tilted(deg)])
    assert normals_agree(g, *PAIR, RULES)[0] == expected


@pytest.mark.parametrize("dz, expected", [(0.0, True), (0.3, True), (0.4, False), (1.0, False)])
def test_side_by_side_rejects_stacked_parallel_planes(dz, expected):
    # Centroids 1 m apart along the plane and dz along the normal: angle = atan2(1, dz) >= 70 deg?
    g = geometry([[0, 0, 0], [1, 0, dz]], [[0, 0, 1], [0, 0, 1]])
    assert side_by_side(g, *PAIR, RULES)[0] == (math.degrees(math.atan2(1, dz)) >= 70) == expected


@pytest.mark.parametrize("offset, expected", [(0.0, True), (0.19, True), (0.21, False)])
def test_planes_close_within_d_max(offset, expected):
    g = geometry([[0, 0, 0], [5, 0, offset]], [[0, 0, 1], [0, 0, 1]])
    assert planes_close(g, *PAIR, RULES)[0] == expected


@pytest.mark.parametrize("delta, expected", [(0.0, True), (19.0, True), (21.0, False)])
def test_colors_close_in_cielab(delta, expected):
    g = geometry([[0, 0, 0], [1, 0, 0]], [[0, 0, 1], [0, 0, 1]], labs=[(50, 0, 0), (50, delta, 0)])
    assert colors_close(g, *PAIR, RULES)[0] == expected
    no_colour = PlaneRules(15.0, 70.0, 0.2, None)
    assert colors_close(g, *PAIR, no_colour)[0]


def _table(parts, colors=None):
    """Statistics of welded rectangles as clusters (one per part) and their adjacency."""
    vertices, faces, part = weld(parts)
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    lab = None if colors is None else np.asarray(colors, float)[part]
    faces_table = st.face_table(tri, area, cross / (2 * area[:, None]), lab, None)
    table = st.aggregate(faces_table, part, len(parts))
    from perch_segmentation.adjacency import face_adjacency, unique_edges

    pairs = face_adjacency(faces, len(vertices))
    return table, unique_edges(part[pairs[:, 0]], part[pairs[:, 1]], len(parts))


def test_merge_coplanar_joins_coplanar_neighbours_but_not_a_corner():
    floor_a = grid_rect((0, 0, 0), (1, 0, 0), (0, 1, 0), 5, 5)
    floor_b = grid_rect((1, 0, 0), (1, 0, 0), (0, 1, 0), 5, 5)
    wall = grid_rect((0, 0, 0), (0, 0, 1), (2, 0, 0), 5, 10)
    table, edges = _table([floor_a, floor_b, wall])
    mapping, merged, _ = merge_coplanar(table, edges, PlaneRules(15.0, 70.0, 0.2, None))
    assert mapping[0] == mapping[1] != mapping[2]
    assert merged[mapping[0], st.AREA] == pytest.approx(2.0)


def test_merge_coplanar_keeps_differently_coloured_flush_pieces_apart():
    wall = grid_rect((0, 0, 0), (1, 0, 0), (0, 1, 0), 5, 5)
    door = grid_rect((1, 0, 0), (1, 0, 0), (0, 1, 0), 5, 5)
    table, edges = _table([wall, door], colors=[(88, 0, 6), (30, 11, 20)])
    assert merge_coplanar(table, edges, RULES)[0].tolist() == [0, 1]
    assert len(set(merge_coplanar(table, edges, PlaneRules(15.0, 70.0, 0.2, None))[0].tolist())) == 1


def test_floor_pieces_are_united_but_not_a_table_top():
    parts = [grid_rect((0, 0, 0), (2, 0, 0), (0, 2, 0), 4, 4),     # floor, room 1
             grid_rect((5, 0, 0.02), (2, 0, 0), (0, 2, 0), 4, 4),  # floor, room 2 (2 cm step)
             grid_rect((1, 1, 0.75), (1, 0, 0), (0, 1, 0), 2, 2),  # table top
             grid_rect((0, 0, 2.5), (0, 2, 0), (2, 0, 0), 4, 4)]   # ceiling (facing down)
    table, _ = _table(parts)
    mapping = boundary_plane_groups(table, np.array([0, 0, 1.0]), (0.0, 2.5), RULES, min_area=0.2)
    assert mapping[0] == mapping[1]
    assert len({mapping[0], mapping[2], mapping[3]}) == 3


def _fold(angle_deg, size=0.1, n=1):
    """Two squares sharing the x axis edge, the second folded up by angle_deg."""
    a = np.radians(angle_deg)
    flat = grid_rect((0, 0, 0), (size, 0, 0), (0, -size, 0), n, n)
    up = grid_rect((0, 0, 0), (0, size * np.cos(a), size * np.sin(a)), (size, 0, 0), n, n)
    return [flat, up]


def _grow(parts, rules):
    vertices, faces, part = weld(parts)
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    table = st.face_table(tri, area, cross / (2 * area[:, None]), None, None)
    from perch_segmentation.adjacency import face_adjacency

    labels, _, _ = grow_clusters(table, face_adjacency(faces, len(vertices)), rules, target=1)
    return labels, part


def _rules(bound=4e-4):
    return MergeRules(energy_bound=bound, color_threshold=None, guard_area=0.01,
                      guard_cos=math.cos(math.radians(15.0)))


def test_step1_merges_a_flat_patch_into_one_cluster():
    labels, _ = _grow([grid_rect((0, 0, 0), (1, 0, 0), (0, 1, 0), 10, 10)], _rules())
    assert len(np.unique(labels)) == 1


@pytest.mark.parametrize("angle, merged", [(5.0, True), (89.0, False)])
def test_step1_does_not_merge_across_a_fold(angle, merged):
    labels, part = _grow(_fold(angle, size=0.05), _rules())
    assert (labels[part == 0][0] == labels[part == 1][0]) == merged


def test_step1_energy_bound_stops_merging_a_curved_strip():
    # A cylinder of radius 1 m: small pieces are flat enough, the whole strip is not.
    angles = np.linspace(0, np.pi / 2, 31)
    parts = []
    for a0, a1 in zip(angles[:-1], angles[1:]):
        p0 = np.array([np.cos(a0), 0, np.sin(a0)])
        p1 = np.array([np.cos(a1), 0, np.sin(a1)])
        parts.append(grid_rect(p0, p1 - p0, (0, 1, 0), 1, 10))
    labels, _ = _grow(parts, _rules(bound=1e-4))
    sizes = np.bincount(labels)
    assert 2 <= len(np.unique(labels)) < 30
    assert sizes.max() < len(labels)


def test_fragments_join_the_plane_they_fit_and_not_a_perpendicular_one():
    wall = grid_rect((0, 0, 0), (2, 0, 0), (0, 0, 2), 10, 10)          # 4 m^2, normal -y
    crumb = grid_rect((2, 0, 0), (0.2, 0.03, 0), (0, 0, 0.4), 2, 2)    # 0.08 m^2, bent 8.5 deg off the wall
    strip = grid_rect((0, 0, 2), (2, 0, 0), (0, -0.05, 0), 10, 1)      # 0.1 m^2, perpendicular ledge
    table, edges = _table([wall, crumb, strip])
    mapping, _, _ = absorb_fragments(table, edges, min_area=0.2, max_rms=0.1, guard_area=0.01,
                                     guard_cos=math.cos(math.radians(15.0)))
    assert mapping[1] == mapping[0]
    assert mapping[2] != mapping[0]
