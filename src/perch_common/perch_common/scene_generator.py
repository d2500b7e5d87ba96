"""Seeded procedural indoor scenes with per-face ground truth (the demo scene and the test oracle).

A scene is built on a voxel grid in its own axis-aligned frame: rooms are carved out of solid,
furniture is added back as solid, and the mesh is the set of voxel faces between free and solid
space. Every vertex is a lattice point shared by its faces, so the result is watertight by
construction, and every face's normal points into free space. Doors and windows are flush,
differently coloured rectangles on walls. A seeded yaw and offset make the scene non-axis-aligned.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from scipy import ndimage

from perch_common.mesh import Mesh
from perch_common.scene_layout import Layout, make_layout
from perch_common.target import TargetVolume
from perch_common.types import PlaneFrame, Surface, SurfaceClass

KINDS = ("room", "l_shaped", "two_rooms", "apartment", "building", "multi_storey")
# m; others 0.1. A building floor is 2-3 M faces at 0.042 m, a multi_storey building 5-8 M.
DEFAULT_RESOLUTION = {"building": 0.042, "multi_storey": 0.042}
FLOORS = (2, 4)   # storeys of a multi_storey building


class SemanticClass(IntEnum):
    """Ground-truth class of a generated face: floor, wall, ceiling, door, window, furniture (or none)."""

    NONE = 0
    FLOOR = 1
    WALL = 2
    CEILING = 3
    DOOR = 4
    WINDOW = 5
    FURNITURE = 6


COLORS = {  # RGB 0-255; furniture gets per-item colours
    SemanticClass.FLOOR: (150, 111, 74),
    SemanticClass.WALL: (224, 220, 208),
    SemanticClass.CEILING: (245, 245, 242),
    SemanticClass.DOOR: (96, 64, 40),
    SemanticClass.WINDOW: (150, 190, 220),
}
# Later classes win at vertices shared by faces of different colours.
COLOR_PRIORITY = (SemanticClass.CEILING, SemanticClass.WALL, SemanticClass.FLOOR,
                  SemanticClass.FURNITURE, SemanticClass.DOOR, SemanticClass.WINDOW)


@dataclass
class GroundTruthPlane:
    """One planar piece of a generated scene, with its class and outward normal."""

    id: int
    semantic_class: SemanticClass
    normal: np.ndarray     # unit, into free space (world frame)
    offset: float          # plane: normal . x = offset
    area: float
    centroid: np.ndarray


@dataclass
class VoxelGrid:
    """Occupancy in the scene's own frame: occupied[i, j, k] covers origin + [i, i+1) * voxel_size."""

    origin: np.ndarray
    voxel_size: float
    occupied: np.ndarray
    world_from_grid: np.ndarray

    def indices(self, points: np.ndarray) -> np.ndarray:
        """(N,3) integer voxel indices of world points (may be out of range)."""
        inv = np.linalg.inv(self.world_from_grid)
        local = np.asarray(points, np.float64) @ inv[:3, :3].T + inv[:3, 3]
        return np.floor((local - self.origin) / self.voxel_size).astype(np.int64)

    def is_free(self, points: np.ndarray) -> np.ndarray:
        """(N,) whether each point lies in a free voxel of the scene."""
        idx = self.indices(points)
        inside = np.all((idx >= 0) & (idx < self.occupied.shape), axis=1)
        out = np.zeros(len(idx), bool)
        ii = idx[inside]
        out[inside] = ~self.occupied[ii[:, 0], ii[:, 1], ii[:, 2]]
        return out


@dataclass
class FurnitureBox:
    """A piece of generated furniture: its kind and axis-aligned box."""

    kind: str
    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray


@dataclass
class GeneratedScene:
    """A generated scene: the mesh, each face's ground-truth plane and class, free space, furniture, target."""

    mesh: Mesh
    face_plane: np.ndarray
    face_class: np.ndarray
    planes: list[GroundTruthPlane]
    free_space: VoxelGrid
    furniture: list[FurnitureBox]
    target: TargetVolume
    world_from_scene: np.ndarray
    kind: str = "room"
    seed: int = 0
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def ground_truth_surfaces(self, min_area: float = 0.2) -> list[Surface]:
        """Each ground-truth plane of at least min_area as a Surface (boundary with holes)."""
        from perch_common.polygons import faces_outline

        surfaces: list[Surface] = []
        colors = self.mesh.face_colors()
        areas = self.mesh.face_areas()
        for plane in self.planes:
            if plane.area < min_area:
                continue
            faces = np.flatnonzero(self.face_plane == plane.id)
            frame = PlaneFrame.from_normal(plane.centroid, plane.normal, self.up)
            surfaces.append(Surface(
                id=len(surfaces), frame=frame, area=float(areas[faces].sum()), face_indices=faces,
                surface_class=SurfaceClass.UNKNOWN, rms_distance=0.0,
                mean_color=np.average(colors[faces], axis=0, weights=areas[faces]),
                boundary=faces_outline(frame, self.mesh.triangles(faces))))
        return surfaces


def generate_scene(seed: int, kind: str = "room", *, noise: float = 0.0, holes: int = 0,
                   ceiling: bool = True, furniture: bool = True, openings: bool = True,
                   resolution: float | None = None, clutter: int = 0,
                   floors: int | None = None) -> GeneratedScene:
    """A seeded scene of the given kind ("room", "l_shaped", "two_rooms", "apartment", "building",
    "multi_storey").

    A building is one floor of 8-12 rooms off two crossing corridors (400-800 m^2), with a doorway
    from every room, furniture in every room, and a target of three volumes: the corridor junction
    and two rooms. A multi_storey building is 2-4 such floors (`floors`, default drawn from the
    seed) on 0.25 m slabs, a stair flight between each pair of storeys under a hole in the slab,
    two shafts through every slab at the corridors' far ends, furniture on every storey, and a
    target of six volumes spread over the storeys. `clutter` adds that many small boxes on the
    floors (class furniture).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown scene kind '{kind}' (use one of {', '.join(KINDS)})")
    if floors is not None and kind != "multi_storey":
        raise ValueError(f"floors {floors}: only a multi_storey scene has floors ({FLOORS[0]}-{FLOORS[1]} of them)")
    if floors is not None and not FLOORS[0] <= floors <= FLOORS[1]:
        raise ValueError(f"floors {floors}: a multi_storey scene has {FLOORS[0]}-{FLOORS[1]} floors")
    resolution = DEFAULT_RESOLUTION.get(kind, 0.1) if resolution is None else resolution
    if not 0.02 <= resolution <= 0.5:
        raise ValueError(f"resolution {resolution} m out of range 0.02-0.5")
    if clutter < 0:
        raise ValueError(f"clutter {clutter}: give a count of 0 or more")
    rng = np.random.default_rng(seed)
    layout = make_layout(kind, rng, resolution, furniture, clutter, floors)
    faces_abc = _boundary_faces(layout.solid)
    lattice, faces, normal_axis, normal_sign, solid_label = faces_abc
    face_class = _classify(normal_axis, normal_sign, solid_label)
    plane_key = _plane_keys(faces, lattice, normal_axis, normal_sign, face_class, solid_label)
    if openings:
        _add_openings(rng, layout, lattice, faces, normal_axis, face_class, plane_key)
    keep = np.ones(len(faces), bool) if ceiling else face_class != SemanticClass.CEILING
    vertices = lattice * resolution
    face_plane = _label_planes(lattice, faces, normal_axis, plane_key)
    if holes:
        keep &= ~_hole_mask(rng, holes, vertices, faces, face_class, face_plane)
    faces, face_class, face_plane, solid_label = faces[keep], face_class[keep], face_plane[keep], solid_label[keep]
    _, face_plane = np.unique(face_plane, return_inverse=True)

    yaw = rng.uniform(0, 2 * np.pi)
    world = np.eye(4)
    world[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    world[:3, 3] = [rng.uniform(-3, 3), rng.uniform(-3, 3), -layout.floor_z * resolution]
    colors = _vertex_colors(rng, len(vertices), faces, face_class, solid_label)
    mesh = Mesh(vertices, faces, colors).transformed(world)
    used, inverse = np.unique(mesh.faces, return_inverse=True)  # drop lattice points no face uses
    mesh = Mesh(mesh.vertices[used], inverse.reshape(-1, 3), mesh.vertex_colors[used])
    if noise > 0:
        mesh.vertices += rng.normal(0.0, noise, mesh.vertices.shape)
    grid = VoxelGrid(np.zeros(3), resolution, layout.solid != 0, world)
    boxes = [FurnitureBox(f.kind, world[:3, :3] @ (f.center * resolution) + world[:3, 3],
                          f.size * resolution, world[:3, :3]) for f in layout.furniture]
    if layout.targets:   # each named volume in full, 0.1-1.3 m above the floor
        target = TargetVolume.union([_box_target(box, world, resolution, box[2], 1.0)
                                     for box in layout.targets])
    else:                # the middle half of the main room
        target = _box_target(layout.rooms[0], world, resolution, layout.rooms[0][2], 0.5)
    scene = GeneratedScene(mesh, face_plane, face_class, [], grid, boxes, target, world, kind, seed)
    scene.planes = _plane_table(mesh, face_plane, face_class)
    return scene


def _box_target(box, world: np.ndarray, resolution: float, floor_z: int, share: float) -> TargetVolume:
    """A target box over the middle `share` of a free box's floor, 1.2 m high from 0.1 m (world frame)."""
    center = np.array([(box[0] + box[3]) / 2, (box[1] + box[4]) / 2, floor_z + 0.7 / resolution])
    return TargetVolume(center=world[:3, :3] @ (center * resolution) + world[:3, 3],
                        size=[share * (box[3] - box[0]) * resolution, share * (box[4] - box[1]) * resolution, 1.2],
                        rotation=world[:3, :3])


def _boundary_faces(solid: np.ndarray):
    """Quads between free and solid voxels, split into triangles wound so normals face free space.

    Returns lattice points (P,3), faces (F,3), normal axis (F,), normal sign (F,), and the
    label of the solid voxel behind each face (F,) (0 structure, >0 furniture id).
    """
    labels = solid
    occupied = labels != 0
    shape = np.array(occupied.shape)
    quads, axes, signs, behind = [], [], [], []
    for axis in range(3):
        order = [axis, (axis + 1) % 3, (axis + 2) % 3]  # (a, b, c) cyclic, b x c = a
        occ = np.transpose(occupied, order)
        lab = np.transpose(labels, order)
        s0, s1 = occ[:-1], occ[1:]
        for sign, mask, solid_at in ((+1, s0 & ~s1, 0), (-1, ~s0 & s1, 1)):
            u, v, w = np.nonzero(mask)
            corners_abc = np.stack([
                np.stack([u + 1, v, w], -1), np.stack([u + 1, v + 1, w], -1),
                np.stack([u + 1, v + 1, w + 1], -1), np.stack([u + 1, v, w + 1], -1)], 1)
            corners = np.empty_like(corners_abc)
            corners[..., order] = corners_abc
            if sign < 0:
                corners = corners[:, ::-1]
            quads.append(corners)
            axes.append(np.full(len(u), axis))
            signs.append(np.full(len(u), sign))
            behind.append(lab[u + solid_at, v, w])
    quads = np.concatenate(quads)
    dims = shape + 1
    ids = (quads[..., 0] * dims[1] + quads[..., 1]) * dims[2] + quads[..., 2]
    faces = np.concatenate([ids[:, [0, 1, 2]], ids[:, [0, 2, 3]]])
    unique_ids, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    lattice = np.stack(np.unravel_index(unique_ids, tuple(dims)), -1).astype(np.float64)
    twice = lambda a: np.concatenate([a, a])  # noqa: E731 - both triangles share quad data
    return lattice, faces, twice(np.concatenate(axes)), twice(np.concatenate(signs)), twice(np.concatenate(behind))


def _classify(axis: np.ndarray, sign: np.ndarray, behind: np.ndarray) -> np.ndarray:
    cls = np.full(len(axis), SemanticClass.WALL, np.uint8)
    cls[(axis == 2) & (sign > 0)] = SemanticClass.FLOOR
    cls[(axis == 2) & (sign < 0)] = SemanticClass.CEILING
    cls[behind > 1] = SemanticClass.FURNITURE  # label 1 is structure, >1 furniture
    return cls


def _plane_keys(faces, lattice, axis, sign, cls, behind) -> np.ndarray:
    """A key per face that differs between faces that can never be one plane."""
    level = lattice[faces[:, 0], axis].astype(np.int64)
    return (((axis * 2 + (sign > 0)) * 100000 + level) * 10 + cls) * 1000 + behind


def _label_planes(lattice, faces, axis, key) -> np.ndarray:
    """Connected components of same-key faces (edge-adjacent in their plane)."""
    groups, group_of = np.unique(key, return_inverse=True)
    order = np.argsort(group_of, kind="stable")   # faces grouped by key, each group in face order
    bounds = np.searchsorted(group_of[order], np.arange(len(groups) + 1))
    plane = np.zeros(len(faces), np.int64)
    centre = lattice[faces].mean(axis=1)
    next_id = 0
    for g in range(len(groups)):
        members = order[bounds[g]:bounds[g + 1]]
        a = axis[members[0]]
        uv = np.floor(centre[members][:, [(a + 1) % 3, (a + 2) % 3]]).astype(np.int64)
        uv -= uv.min(axis=0)
        grid = np.zeros(uv.max(axis=0) + 1, bool)
        grid[uv[:, 0], uv[:, 1]] = True
        comp, count = ndimage.label(grid)
        plane[members] = next_id + comp[uv[:, 0], uv[:, 1]] - 1
        next_id += count
    return plane


def _add_openings(rng, layout: Layout, lattice, faces, axis, cls, key) -> None:
    """Paint flush doors and windows onto walls (in place: class and plane key)."""
    res = layout.resolution
    centre = lattice[faces].mean(axis=1)
    walls = np.flatnonzero(cls == SemanticClass.WALL)
    wall_keys = np.unique(key[walls])
    rng.shuffle(wall_keys)
    placed = 0
    wanted = max(2, len(layout.rooms) + 1)
    for wk in wall_keys:
        if placed >= wanted:
            break
        members = walls[key[walls] == wk]
        a = axis[members[0]]
        along = (a + 1) % 3 if (a + 1) % 3 != 2 else (a + 2) % 3
        coord = centre[members, along]
        height = centre[members, 2] - layout.floor_below(centre[members, 2])   # above its own storey's floor
        lo, hi = coord.min(), coord.max()
        is_door = placed % 2 == 0
        width = (0.9 if is_door else rng.uniform(1.0, 1.6)) / res
        bottom, top = (0.0, 2.1 / res) if is_door else (0.9 / res, 0.9 / res + rng.uniform(1.0, 1.4) / res)
        if hi - lo < width + 4:
            continue
        start = np.round(rng.uniform(lo + 2, hi - width - 2))
        inside = (coord >= start) & (coord <= start + width) & (height >= bottom) & (height <= top)
        # Only a complete rectangle of wall (no furniture, no corner) becomes an opening.
        if inside.sum() < 2 * int(width) * int(top - bottom) * 0.95:
            continue
        cls[members[inside]] = SemanticClass.DOOR if is_door else SemanticClass.WINDOW
        key[members[inside]] = key[members[inside]] * 10 + 1 + placed
        placed += 1


def _hole_mask(rng, count, vertices, faces, cls, plane) -> np.ndarray:
    """Remove `count` discs (0.15-0.35 m) of wall faces, as reconstructions leave."""
    centre = vertices[faces].mean(axis=1)
    walls = np.flatnonzero(cls == SemanticClass.WALL)
    mask = np.zeros(len(faces), bool)
    for f in rng.choice(walls, size=min(count, len(walls)), replace=False):
        same = plane == plane[f]
        mask |= same & (np.linalg.norm(centre - centre[f], axis=1) < rng.uniform(0.15, 0.35))
    return mask


def _vertex_colors(rng, n_vertices, faces, cls, behind) -> np.ndarray:
    face_rgb = np.zeros((len(faces), 3), np.int64)
    for c, rgb in COLORS.items():
        face_rgb[cls == c] = rgb
    furniture_ids = np.unique(behind[cls == SemanticClass.FURNITURE])
    palette = rng.integers(40, 200, size=(len(furniture_ids), 3))
    for fid, rgb in zip(furniture_ids, palette):
        face_rgb[(cls == SemanticClass.FURNITURE) & (behind == fid)] = rgb
    colors = np.zeros((n_vertices, 3), np.uint8)
    for c in COLOR_PRIORITY:
        sel = cls == c
        colors[faces[sel].ravel()] = np.repeat(face_rgb[sel], 3, axis=0)
    return colors


def _plane_table(mesh: Mesh, face_plane, face_class) -> list[GroundTruthPlane]:
    areas = mesh.face_areas()
    normals = mesh.face_normals()
    centroids = mesh.face_centroids()
    n = int(face_plane.max()) + 1 if len(face_plane) else 0
    area = np.bincount(face_plane, areas, n)
    # Area-weighted sums per plane in one pass each (a loop over planes is quadratic on a building).
    normal = np.stack([np.bincount(face_plane, normals[:, k] * areas, n) for k in range(3)], 1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    centroid = np.stack([np.bincount(face_plane, centroids[:, k] * areas, n) for k in range(3)], 1) / area[:, None]
    first = np.full(n, len(face_plane))
    np.minimum.at(first, face_plane, np.arange(len(face_plane)))
    return [GroundTruthPlane(pid, SemanticClass(int(face_class[first[pid]])), normal[pid],
                             float(normal[pid] @ centroid[pid]), float(area[pid]), centroid[pid])
            for pid in range(n)]
