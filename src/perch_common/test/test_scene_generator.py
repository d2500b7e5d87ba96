"""Generator invariants: watertight, fully labelled, realistic scale, reproducible."""

import numpy as np
import pytest
import trimesh

from perch_common.scene_generator import KINDS, SemanticClass, generate_scene

FLOOR_M2 = {"building": (400, 800)}   # floor plus furniture footprint (per storey); others 20-62 m^2
COARSE = {"building": 0.1, "multi_storey": 0.1}


@pytest.fixture(scope="module", params=KINDS)
def scene(request):
    # The buildings at 0.1 m (not their default 0.042 m): the same layout at a fifth of the faces.
    return generate_scene(7, request.param, resolution=COARSE.get(request.param))


def test_watertight_with_normals_into_free_space(scene):
    tm = trimesh.Trimesh(scene.mesh.vertices, scene.mesh.faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume < 0  # normals point inwards, into the rooms
    # Points just in front of faces are free; just behind are solid.
    centre, normal = scene.mesh.face_centroids(), scene.mesh.face_normals()
    pick = np.random.default_rng(0).choice(len(centre), 500, replace=False)
    assert scene.free_space.is_free(centre[pick] + 0.03 * normal[pick]).mean() > 0.99
    assert (~scene.free_space.is_free(centre[pick] - 0.03 * normal[pick])).mean() > 0.99


def test_every_face_labelled_and_planes_consistent(scene):
    assert (scene.face_plane >= 0).all() and len(scene.face_plane) == scene.mesh.num_faces
    assert set(np.unique(scene.face_class)) <= {c.value for c in SemanticClass if c != SemanticClass.NONE}
    areas = scene.mesh.face_areas()
    normals = scene.mesh.face_normals()
    for plane in scene.planes:
        faces = scene.face_plane == plane.id
        assert areas[faces].sum() == pytest.approx(plane.area)
        assert np.allclose(normals[faces], plane.normal, atol=1e-6)
        assert len(np.unique(scene.face_class[faces])) == 1


def test_realistic_scale(scene):
    areas = scene.mesh.face_areas()
    centroids = scene.mesh.face_centroids()
    # The lowest storey (a multi_storey building: below its first slab).
    lowest = centroids[:, 2] < 3.2 + 0.5 if scene.kind == "multi_storey" else np.ones(len(areas), bool)
    floor = areas[(scene.face_class == SemanticClass.FLOOR) & lowest].sum()
    furniture_footprint = sum(b.size[0] * b.size[1] for b in scene.furniture if b.center[2] < 3.2)
    low, high = FLOOR_M2.get(scene.kind.replace("multi_storey", "building"), (20, 62))
    assert low <= floor + furniture_footprint <= high
    ceiling_z = centroids[(scene.face_class == SemanticClass.CEILING) & lowest][:, 2]
    assert 2.4 - 1e-6 <= np.median(ceiling_z) <= 3.2 + 1e-6
    assert scene.mesh.vertices[:, 2].min() == pytest.approx(0.0)


def test_openings_are_flush_and_coloured_differently(scene):
    doors = scene.face_class == SemanticClass.DOOR
    walls = scene.face_class == SemanticClass.WALL
    assert doors.any() and (scene.face_class == SemanticClass.WINDOW).any()
    colors = scene.mesh.face_colors()
    assert np.linalg.norm(np.median(colors[doors], 0) - np.median(colors[walls], 0)) > 0.3
    door_plane = scene.planes[int(scene.face_plane[np.flatnonzero(doors)[0]])]
    coplanar_walls = [p for p in scene.planes if p.semantic_class == SemanticClass.WALL
                      and p.normal @ door_plane.normal > 0.999 and abs(p.offset - door_plane.offset) < 1e-6]
    assert coplanar_walls, "a door lies in the plane of a wall"


def test_seeds_reproducible_and_distinct():
    a, b, c = generate_scene(3, "two_rooms"), generate_scene(3, "two_rooms"), generate_scene(4, "two_rooms")
    assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.face_plane, b.face_plane)
    assert a.mesh.num_faces != c.mesh.num_faces or not np.allclose(a.mesh.vertices, c.mesh.vertices)


def test_options_noise_holes_ceiling():
    clean = generate_scene(5, "room")
    noisy = generate_scene(5, "room", noise=0.005)
    assert noisy.mesh.num_faces == clean.mesh.num_faces
    assert np.std(noisy.mesh.vertices - clean.mesh.vertices) == pytest.approx(0.005, rel=0.1)
    holed = generate_scene(5, "room", holes=3)
    assert holed.mesh.num_faces < clean.mesh.num_faces
    assert not trimesh.Trimesh(holed.mesh.vertices, holed.mesh.faces, process=False).is_watertight
    open_top = generate_scene(5, "room", ceiling=False)
    assert not (open_top.face_class == SemanticClass.CEILING).any()


def test_ground_truth_surfaces_cover_planes():
    scene = generate_scene(2, "l_shaped")
    surfaces = scene.ground_truth_surfaces(min_area=0.5)
    big = [p for p in scene.planes if p.area >= 0.5]
    assert len(surfaces) == len(big)
    from perch_common.polygons import polygons_area
    for s in surfaces:
        assert polygons_area(s.boundary) == pytest.approx(s.area, rel=1e-6)
        assert np.allclose(np.cross(s.frame.axis_u, s.frame.axis_v), s.frame.normal)


def test_target_inside_main_room():
    scene = generate_scene(9, "apartment")
    points = scene.target.sample(200, seed=1)
    assert len(points) == 200 and scene.target.contains(points).all()
    assert scene.free_space.is_free(points).mean() > 0.7  # furniture may intrude a little


def test_unknown_kind_rejected():
    with pytest.raises(ValueError, match="unknown scene kind 'castle'"):
        generate_scene(0, "castle")


def test_building_floor_at_default_resolution():
    """8-12 rooms off corridors, 2-3 M faces, every room reachable through its doorway, three targets."""
    from scipy import ndimage

    from perch_common.scene_generator import DEFAULT_RESOLUTION

    scene = generate_scene(1, "building")
    assert 2_000_000 <= scene.mesh.num_faces <= 3_000_000
    grid = scene.free_space
    assert grid.voxel_size == DEFAULT_RESOLUTION["building"]
    level = int(round(1.0 / grid.voxel_size)) + 2          # 1 m above the floor (2 voxels of margin)
    free = ~grid.occupied[:, :, level]
    _, components = ndimage.label(free)
    assert components == 1, f"{components} separate free regions at 1 m: a room without a doorway"
    doorway_level = ~grid.occupied[:, :, int(round(2.3 / grid.voxel_size)) + 2]   # above the 2.1 m doorways
    _, pieces = ndimage.label(doorway_level)
    assert 8 + 1 <= pieces <= 12 + 1, pieces   # the rooms, and the two crossing corridors as one piece
    assert len(scene.furniture) >= 8
    volumes = scene.target.volumes()
    assert len(volumes) == 3
    points = scene.target.sample(300, seed=2)
    assert len(points) == 300 and scene.target.contains(points).all()
    for volume in volumes:   # equal weighting: each volume gets a third of the points
        assert volume.contains(points).sum() == pytest.approx(100, abs=2)
    assert scene.free_space.is_free(points).mean() > 0.9


def test_building_clutter_adds_small_furniture():
    bare = generate_scene(2, "building", resolution=0.1)
    cluttered = generate_scene(2, "building", resolution=0.1, clutter=30)
    added = [f for f in cluttered.furniture if f.kind == "clutter"]
    assert 20 <= len(added) <= 30 and len(cluttered.furniture) == len(bare.furniture) + len(added)
    assert all(np.all(f.size <= 0.5 + 1e-9) for f in added)


def test_multi_storey_building_stairs_shafts_and_targets_on_several_storeys():
    """2-4 storeys of the building plan, each reachable from the one below by its stair flight,
    two shafts through every slab, six target volumes over the storeys, every storey furnished."""
    from scipy import ndimage

    from perch_common.scene_generator import DEFAULT_RESOLUTION

    assert DEFAULT_RESOLUTION["multi_storey"] == DEFAULT_RESOLUTION["building"]
    for floors in (2, 3, 4):
        scene = generate_scene(5, "multi_storey", resolution=0.15, floors=floors)
        grid = scene.free_space
        res = grid.voxel_size
        tm = trimesh.Trimesh(scene.mesh.vertices, scene.mesh.faces, process=False)
        assert tm.is_watertight and tm.is_winding_consistent
        # Storey floors: large up-facing areas at `floors` distinct heights, one pitch apart.
        centroids, areas = scene.mesh.face_centroids(), scene.mesh.face_areas()
        up = scene.face_class == SemanticClass.FLOOR
        levels, inverse = np.unique(np.round(centroids[up, 2], 3), return_inverse=True)
        level_area = np.bincount(inverse, weights=areas[up])
        storeys = levels[level_area > 100]
        assert len(storeys) == floors, (storeys, level_area.max())
        pitch = np.diff(storeys)
        assert np.allclose(pitch, pitch[0]) and 2.4 + 0.2 <= pitch[0] <= 3.2 + 0.3
        # Stair treads: small up-facing areas between the storeys' floors.
        treads = levels[(level_area < 5) & (levels > storeys[0]) & (levels < storeys[-1])]
        assert len(treads) >= 10 * (floors - 1)
        # Everything free is one connected space (rooms through doorways, storeys through the
        # stairs and shafts), and a shaft is free from the lowest floor to the top ceiling.
        _, pieces = ndimage.label(~grid.occupied)
        assert pieces == 1
        column_free = (~grid.occupied[:, :, 2:-2]).all(axis=2)   # inside the 2 solid voxels of margin
        assert column_free.sum() >= 2 * (2.0 / res) * (1.8 / res) * 0.9   # two shafts of 2 m x >= 1.8 m
        # Walls higher than a storey: the shafts' walls.
        tall = [p for p in scene.planes if p.semantic_class == SemanticClass.WALL and p.area > 0]
        wall_faces = scene.face_class == SemanticClass.WALL
        heights = [np.ptp(centroids[(scene.face_plane == p.id) & wall_faces, 2]) for p in tall]
        assert max(heights) > pitch[0] * (floors - 1)
        volumes = scene.target.volumes()
        assert len(volumes) == 6
        volume_storeys = {int(np.argmin(abs(storeys - (v.center[2] - 0.7)))) for v in volumes}
        assert volume_storeys == set(range(floors))
        points = scene.target.sample(600, seed=2)
        assert scene.target.contains(points).all() and scene.free_space.is_free(points).mean() > 0.85
        furniture_storeys = {int(np.argmin(abs(storeys - (f.center[2] - f.size[2] / 2)))) for f in scene.furniture}
        assert furniture_storeys == set(range(floors))
    with pytest.raises(ValueError, match="floors 5"):
        generate_scene(5, "multi_storey", floors=5)
    with pytest.raises(ValueError, match="only a multi_storey scene has floors"):
        generate_scene(5, "building", floors=2)
