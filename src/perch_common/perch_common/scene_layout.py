"""Room layouts on a voxel grid for the scene generator (all sizes in voxels)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STRUCTURE = 1  # label of walls, floor and ceiling; furniture items are 2, 3, ...
MARGIN = 2     # solid voxels kept around the rooms


@dataclass
class FurnitureItem:
    """A furniture box placed in the voxel layout."""

    kind: str
    center: np.ndarray  # voxel units, scene frame
    size: np.ndarray


@dataclass
class Layout:
    """The voxel layout of a generated scene: solid labels, room boxes and furniture."""

    resolution: float
    solid: np.ndarray                 # int labels: 0 free, 1 structure, >1 furniture
    rooms: list[tuple[int, ...]]      # free boxes (x0, y0, z0, x1, y1, z1), main room first
    floor_z: int
    furniture: list[FurnitureItem] = field(default_factory=list)
    targets: list[tuple[int, ...]] = field(default_factory=list)   # free boxes to observe (default: main room)
    storeys: list[int] = field(default_factory=list)   # floor level of each storey, lowest first (empty: floor_z)

    def floor_below(self, z: np.ndarray) -> np.ndarray:
        """The floor level (voxels) of the storey each height `z` (voxels) lies in."""
        levels = np.asarray(self.storeys or [self.floor_z])
        return levels[np.clip(np.searchsorted(levels, z, side="right") - 1, 0, len(levels) - 1)]


def make_layout(kind: str, rng: np.random.Generator, res: float, with_furniture: bool, clutter: int = 0,
                floors: int | None = None) -> Layout:
    """The voxel layout of a scene kind: rooms carved from solid, doorways, furniture, clutter
    (`floors`: storeys of a multi_storey building, default drawn from 2-4)."""
    m = lambda metres: int(round(metres / res))  # noqa: E731 - metres to voxels
    height = m(rng.uniform(2.4, 3.2))
    wall = max(1, m(0.2))
    targets: list[tuple[int, int, int, int]] = []
    furnished = 2
    if kind == "multi_storey":
        return _multi_storey(rng, m, res, height, wall, with_furniture, clutter, floors)
    if kind == "building":
        boxes, doorways, targets, furnished = _building_plan(rng, m, wall)
    elif kind == "room":
        w = rng.uniform(4.5, 7.5)
        boxes = [(0, 0, m(w), m(rng.uniform(20, 60) / w))]
        doorways = []
    elif kind == "l_shaped":
        w1, d1 = rng.uniform(5, 7), rng.uniform(3.5, 4.5)
        w2, d2 = rng.uniform(3, 4), rng.uniform(3, 4.5)
        boxes = [(0, 0, m(w1), m(d1)), (0, m(d1), m(w2), m(d1) + m(d2))]
        doorways = []
    else:
        w1, d1 = rng.uniform(5, 6.5), rng.uniform(4, 5.5)
        w2 = rng.uniform(3, 4.5) if kind == "two_rooms" else rng.uniform(3, 4)
        x2 = m(w1) + wall
        boxes = [(0, 0, m(w1), m(d1)), (x2, 0, x2 + m(w2), m(d1))]
        door_y = int(rng.integers(m(0.6), m(d1) - m(1.5)))
        doorways = [(m(w1), door_y, x2, door_y + m(0.9))]
        if kind == "apartment":  # an alcove off the main room makes it L-shaped
            boxes.append((0, m(d1), m(rng.uniform(2.5, 3.5)), m(d1) + m(rng.uniform(2.0, 3.0))))
    x_max = max(b[2] for b in boxes)
    y_max = max(b[3] for b in boxes)
    z0 = MARGIN
    shape = (x_max + 2 * MARGIN, y_max + 2 * MARGIN, height + 2 * MARGIN)
    solid = np.full(shape, STRUCTURE, np.int64)
    rooms = []
    for x0, y0, x1, y1 in boxes:
        room = (x0 + MARGIN, y0 + MARGIN, z0, x1 + MARGIN, y1 + MARGIN, z0 + height)
        solid[room[0]:room[3], room[1]:room[4], room[2]:room[5]] = 0
        rooms.append(room)
    for x0, y0, x1, y1 in doorways:
        solid[x0 + MARGIN:x1 + MARGIN, y0 + MARGIN:y1 + MARGIN, z0:z0 + m(2.1)] = 0
    layout = Layout(res, solid, rooms, z0)
    layout.targets = [(x0 + MARGIN, y0 + MARGIN, z0, x1 + MARGIN, y1 + MARGIN, z0 + height)
                      for x0, y0, x1, y1 in targets]
    blocked = _doorway_mask(shape, doorways, m(0.8))
    if with_furniture:
        for room in rooms[:furnished]:
            _furnish(rng, layout, room, blocked, m)
    if clutter:
        _scatter_clutter(rng, layout, blocked, clutter, m)
    return layout


def _building_plan(rng, m, wall: int, rooms_per_quadrant: tuple[int, int] = (2, 3)):
    """A floor of 8-12 rooms off two crossing corridors (voxels): room and corridor boxes (rooms
    first, corridors last), a doorway from every room into the corridor it faces, the targets
    (corridor junction and two rooms) and how many boxes get furniture (the rooms)."""
    corridor = m(rng.uniform(1.8, 2.4))
    depth = {side: m(rng.uniform(6.0, 8.0)) for side in ("south", "north")}
    low, high = rooms_per_quadrant
    per_quadrant = {q: int(rng.integers(low, high + 1)) for q in ("sw", "se", "nw", "ne")}
    widths = {q: [m(rng.uniform(4.5, 6.5)) for _ in range(n)] for q, n in per_quadrant.items()}
    span = {q: sum(w) + wall * (len(w) - 1) for q, w in widths.items()}
    west = max(span["sw"], span["nw"])
    east = max(span["se"], span["ne"])
    x_corridor, y_corridor = west + wall, depth["south"] + wall
    x_max = x_corridor + corridor + wall + east
    y_max = y_corridor + corridor + wall + depth["north"]
    rooms, doorways = [], []
    door = m(0.9)
    for quadrant, room_widths in widths.items():
        x = 0 if quadrant[1] == "w" else x_corridor + corridor + wall
        width_total = west if quadrant[1] == "w" else east
        y0, y1 = (0, depth["south"]) if quadrant[0] == "s" else (y_corridor + corridor + wall, y_max)
        for i, w in enumerate(room_widths):
            if i == len(room_widths) - 1:   # the last room fills the quadrant up to the corridor wall
                w = (0 if quadrant[1] == "w" else x_corridor + corridor + wall) + width_total - x
            rooms.append((x, y0, x + w, y1))
            start = x + int(rng.integers(m(0.4), max(m(0.4) + 1, w - door - m(0.4))))
            wall_y = (depth["south"], y_corridor) if quadrant[0] == "s" else (y_corridor + corridor, y0)
            doorways.append((start, wall_y[0], start + door, wall_y[1]))
            x += w + wall
    corridors = [(0, y_corridor, x_max, y_corridor + corridor), (x_corridor, 0, x_corridor + corridor, y_max)]
    junction = (x_corridor, y_corridor, x_corridor + corridor, y_corridor + corridor)
    chosen = rng.choice(len(rooms), size=2, replace=False)
    targets = [junction, *(rooms[int(i)] for i in sorted(chosen))]
    return rooms + corridors, doorways, targets, len(rooms)


# Storeys of a multi_storey building -> rooms per quadrant of each floor plan: ~5-8 M faces at
# 0.042 m whatever the count (a building floor of 8-12 rooms is 2-3 M faces).
STOREY_ROOMS = {2: (3, 3), 3: (2, 3), 4: (2, 2)}
TARGET_VOLUMES = 6   # of a multi_storey building, spread over its storeys


def _multi_storey(rng, m, res: float, height: int, wall: int, with_furniture: bool, clutter: int,
                  floors: int | None = None) -> Layout:
    """2-4 storeys of the building floor plan on slabs, joined by a stair flight between each pair
    of storeys (in the north-south corridor, alternately at its south and north end) and two
    shafts through every slab (both ends of the east-west corridor).

    Each storey has its own furniture; the target is six volumes spread over the storeys (each
    storey's corridor junction first, then rooms)."""
    floors = int(rng.integers(2, 5)) if floors is None else floors
    boxes, doorways, _, furnished = _building_plan(rng, m, wall, STOREY_ROOMS[floors])
    slab = max(1, m(0.25))
    pitch = height + slab
    x_max = max(b[2] for b in boxes)
    y_max = max(b[3] for b in boxes)
    shape = (x_max + 2 * MARGIN, y_max + 2 * MARGIN, floors * pitch - slab + 2 * MARGIN)
    solid = np.full(shape, STRUCTURE, np.int64)
    storeys = [MARGIN + k * pitch for k in range(floors)]
    rooms = []
    for z0 in storeys:
        for x0, y0, x1, y1 in boxes:
            room = (x0 + MARGIN, y0 + MARGIN, z0, x1 + MARGIN, y1 + MARGIN, z0 + height)
            solid[room[0]:room[3], room[1]:room[4], room[2]:room[5]] = 0
            rooms.append(room)
        for x0, y0, x1, y1 in doorways:
            solid[x0 + MARGIN:x1 + MARGIN, y0 + MARGIN:y1 + MARGIN, z0:z0 + m(2.1)] = 0
    ew, ns = boxes[furnished], boxes[furnished + 1]   # the east-west and north-south corridors
    for k in range(floors - 1):
        _stairs(solid, ns, k % 2 == 0, storeys[k], pitch, height, m)
    shaft = m(2.0)
    for x0, y0, x1, y1 in ((ew[0], ew[1], ew[0] + shaft, ew[3]), (ew[2] - shaft, ew[1], ew[2], ew[3])):
        solid[x0 + MARGIN:x1 + MARGIN, y0 + MARGIN:y1 + MARGIN, storeys[0]:storeys[-1] + height] = 0
    layout = Layout(res, solid, rooms, storeys[0], storeys=storeys)
    per_storey = len(boxes)
    junction = (ns[0], ew[1], ns[2], ew[3])
    picks: list[tuple[int, ...]] = []
    for i in range(TARGET_VOLUMES):
        k = i % floors
        box = junction if i < floors else boxes[int(rng.choice(
            [r for r in range(furnished) if boxes[r] not in [p[1] for p in picks if p[0] == k]]))]
        picks.append((k, box))
    layout.targets = [(x0 + MARGIN, y0 + MARGIN, storeys[k], x1 + MARGIN, y1 + MARGIN, storeys[k] + height)
                      for k, (x0, y0, x1, y1) in picks]
    blocked = _doorway_mask(shape, doorways, m(0.8))
    if with_furniture:
        for k in range(floors):
            for room in rooms[k * per_storey:k * per_storey + furnished]:
                _furnish(rng, layout, room, blocked, m)
    if clutter:
        _scatter_clutter(rng, layout, blocked, clutter, m)
    return layout


def _stairs(solid, corridor, from_south: bool, z0: int, pitch: int, height: int, m) -> None:
    """A straight flight in the north-south corridor (which no doorway opens onto) from the
    storey at z0 up to the next (one pitch), against its west wall, starting at its south or
    north end, under a hole in the slab above."""
    steps = int(np.ceil(pitch / m(0.18)))
    run = max(1, m(0.27))
    width = min(m(1.1), corridor[2] - corridor[0] - m(0.6))
    x0 = corridor[0] + MARGIN
    length = steps * run
    y_start = corridor[1] + MARGIN if from_south else corridor[3] + MARGIN - length
    # The hole first (the top step fills it again), one voxel wider than the flight: a step whose
    # top meets the slab's underside would otherwise touch the slab along an edge only (a
    # non-manifold mesh edge).
    solid[x0:x0 + width + 1, y_start:y_start + length, z0 + height:z0 + pitch] = 0
    for j in range(steps):
        top = z0 + int(round((j + 1) * pitch / steps))
        y = y_start + j * run if from_south else y_start + length - (j + 1) * run
        solid[x0:x0 + width, y:y + run, z0:top] = STRUCTURE


def _scatter_clutter(rng, layout: Layout, blocked: np.ndarray, count: int, m) -> None:
    """`count` small boxes (0.2-0.5 m) on the floors, clear of doorways and other items (furniture class)."""
    footprints: dict[int, np.ndarray] = {}   # per storey: its floor's occupied cells
    for _ in range(count):
        room = layout.rooms[int(rng.integers(len(layout.rooms)))]
        x0, y0, z0, x1, y1, _ = room
        if z0 not in footprints:
            footprints[z0] = blocked | np.any(layout.solid[:, :, z0:z0 + 1] > 0, axis=2)
        footprint = footprints[z0]
        size = [max(1, m(rng.uniform(0.2, 0.5))) for _ in range(3)]
        for _ in range(20):
            bx = int(rng.integers(x0 + 1, max(x0 + 2, x1 - size[0] - 1)))
            by = int(rng.integers(y0 + 1, max(y0 + 2, y1 - size[1] - 1)))
            if footprint[bx - 1:bx + size[0] + 1, by - 1:by + size[1] + 1].any():
                continue
            label = STRUCTURE + 1 + len(layout.furniture)
            layout.solid[bx:bx + size[0], by:by + size[1], z0:z0 + size[2]] = label
            footprint[bx - 1:bx + size[0] + 1, by - 1:by + size[1] + 1] = True
            layout.furniture.append(FurnitureItem(
                "clutter", np.array([bx + size[0] / 2, by + size[1] / 2, z0 + size[2] / 2]),
                np.array(size, np.float64)))
            break


def _doorway_mask(shape, doorways, clearance: int) -> np.ndarray:
    """Floor cells that must stay free so doorways remain passable."""
    mask = np.zeros(shape[:2], bool)
    for x0, y0, x1, y1 in doorways:
        if x1 - x0 <= y1 - y0:   # the door passes through a wall across x: keep clear in front along x
            mask[max(0, x0 + MARGIN - clearance):x1 + MARGIN + clearance, y0 + MARGIN:y1 + MARGIN] = True
        else:
            mask[x0 + MARGIN:x1 + MARGIN, max(0, y0 + MARGIN - clearance):y1 + MARGIN + clearance] = True
    return mask


# kind: (width, depth, height) in metres; "wall" items stand against a wall, others near one.
FURNITURE = {
    "table": ((1.2, 0.8, 0.75), False),
    "chair": ((0.5, 0.5, 0.9), False),
    "shelf": ((1.0, 0.4, 1.9), True),
    "cabinet": ((0.9, 0.6, 0.9), True),
}


def _furnish(rng, layout: Layout, room, blocked, m) -> None:
    x0, y0, z0, x1, y1, _ = room
    footprint = blocked.copy()
    for kind in ("table", "chair", "chair", "shelf", "cabinet", "table"):
        (w, d, h), against = FURNITURE[kind]
        for _ in range(40):
            side = int(rng.integers(4))
            gap = 0 if against else m(rng.uniform(0.2, 0.4))
            along = (x1 - x0) if side < 2 else (y1 - y0)
            length, depth = m(w), m(d)
            if along < length + 4:
                break
            s = int(rng.integers(2, along - length - 1))
            if side == 0:
                box = (x0 + s, y0 + gap, x0 + s + length, y0 + gap + depth)
            elif side == 1:
                box = (x0 + s, y1 - gap - depth, x0 + s + length, y1 - gap)
            elif side == 2:
                box = (x0 + gap, y0 + s, x0 + gap + depth, y0 + s + length)
            else:
                box = (x1 - gap - depth, y0 + s, x1 - gap, y0 + s + length)
            bx0, by0, bx1, by1 = box
            # One voxel of free margin around each item keeps the mesh manifold.
            if footprint[bx0 - 1:bx1 + 1, by0 - 1:by1 + 1].any():
                continue
            label = STRUCTURE + 1 + len(layout.furniture)
            _build(layout.solid, kind, box, z0, m(h), label, m)
            footprint[bx0 - 1:bx1 + 1, by0 - 1:by1 + 1] = True
            layout.furniture.append(FurnitureItem(
                kind, np.array([(bx0 + bx1) / 2, (by0 + by1) / 2, z0 + m(h) / 2]),
                np.array([bx1 - bx0, by1 - by0, m(h)], np.float64)))
            break


def _build(solid, kind, box, z0, h, label, m) -> None:
    bx0, by0, bx1, by1 = box
    if kind in ("shelf", "cabinet"):
        solid[bx0:bx1, by0:by1, z0:z0 + h] = label
        return
    top = max(1, m(0.05))
    seat = h if kind == "table" else m(0.45)
    solid[bx0:bx1, by0:by1, z0 + seat - top:z0 + seat] = label
    for lx in (bx0, bx1 - 1):
        for ly in (by0, by1 - 1):
            solid[lx, ly, z0:z0 + seat] = label
    if kind == "chair":  # backrest along the +y side
        solid[bx0:bx1, by1 - 1, z0 + seat:z0 + h] = label
