"""Hand-built test environments: rooms from a floor outline, walls with holes, boxes as furniture.

Every planar piece is triangulated from its polygon; the pieces given as filter input come back
as Surfaces with their faces and boundary, so each test knows the exact answer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mapbox_earcut
import numpy as np

from perch_common.mesh import Mesh
from perch_common.types import PlaneFrame, Surface

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class Builder:
    vertices: list = field(default_factory=list)
    faces: list = field(default_factory=list)
    pieces: list = field(default_factory=list)  # (name, frame, rings, face index array)
    count: int = 0

    def piece(self, name: str, frame: PlaneFrame, rings: list) -> None:
        """A planar polygon (outer ring + holes, plane coordinates); faces wound along frame.normal."""
        rings = [np.asarray(r, np.float64) for r in rings]
        pts = np.concatenate(rings)
        tri = mapbox_earcut.triangulate_float64(pts, np.cumsum([len(r) for r in rings]).astype(np.uint32))
        tri = tri.astype(np.int64).reshape(-1, 3)
        world = frame.to_world(pts)
        t = world[tri]
        flip = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) @ frame.normal < 0
        tri[flip] = tri[flip][:, ::-1]
        base = sum(len(v) for v in self.vertices)
        self.vertices.append(world)
        self.faces.append(tri + base)
        self.pieces.append((name, frame, rings, np.arange(self.count, self.count + len(tri))))
        self.count += len(tri)

    def quad(self, name: str, corners: np.ndarray, normal: np.ndarray, holes: list | None = None) -> None:
        """A planar polygon given by world corners, facing `normal`, with world-coordinate holes."""
        corners = np.asarray(corners, np.float64)
        frame = PlaneFrame.from_normal(corners.mean(axis=0), normal, UP)
        rings = [frame.to_plane(corners)] + [frame.to_plane(np.asarray(h, np.float64)) for h in holes or []]
        self.piece(name, frame, rings)

    def box(self, name: str, lo, hi, bottom: bool = False) -> None:
        """An axis-aligned solid box seen from outside (no bottom face by default: it stands on the floor)."""
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        self.quad(f"{name}.top", [[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], [0, 0, 1])
        if bottom:
            self.quad(f"{name}.bottom", [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]], [0, 0, -1])
        self.quad(f"{name}.-x", [[x0, y0, z0], [x0, y1, z0], [x0, y1, z1], [x0, y0, z1]], [-1, 0, 0])
        self.quad(f"{name}.+x", [[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], [1, 0, 0])
        self.quad(f"{name}.-y", [[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], [0, -1, 0])
        self.quad(f"{name}.+y", [[x0, y1, z0], [x1, y1, z0], [x1, y1, z1], [x0, y1, z1]], [0, 1, 0])

    def room(self, name: str, outline, height: float, wall_holes: dict | None = None) -> None:
        """Floor, ceiling and inward-facing walls of a room with a counter-clockwise floor `outline`.

        wall_holes: {wall index: [(s0, s1, z0, z1), ...]} rectangles along wall i (s from its first corner).
        """
        outline = np.asarray(outline, np.float64)
        k = len(outline)
        self.piece(f"{name}.floor", PlaneFrame(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), UP.copy()),
                   [outline])
        ceiling = PlaneFrame(np.array([0, 0, height]), np.array([0, 1.0, 0]), np.array([1.0, 0, 0]), -UP)
        self.piece(f"{name}.ceiling", ceiling, [outline[:, ::-1]])
        for i in range(k):
            a, b = outline[i], outline[(i + 1) % k]
            along = (b - a) / np.linalg.norm(b - a)
            inward = np.array([-along[1], along[0], 0.0])
            corners = [[*a, 0], [*b, 0], [*b, height], [*a, height]]
            holes = []
            for s0, s1, z0, z1 in (wall_holes or {}).get(i, []):
                p0, p1 = a + s0 * along, a + s1 * along
                holes.append([[*p0, z0], [*p1, z0], [*p1, z1], [*p0, z1]])
            self.quad(f"{name}.wall{i}", corners, inward, holes)

    def mesh(self, subdivisions: int = 0) -> Mesh:
        """The mesh; each subdivision splits every face into 4 (face f becomes 4f .. 4f+3)."""
        vertices, faces = np.concatenate(self.vertices), np.concatenate(self.faces)
        for _ in range(subdivisions):
            a, b, c = faces.T
            n = len(vertices)
            mids = np.concatenate([(vertices[a] + vertices[b]) / 2, (vertices[b] + vertices[c]) / 2,
                                   (vertices[c] + vertices[a]) / 2])
            count = np.arange(len(faces))
            ab, bc, ca = n + count, n + len(faces) + count, n + 2 * len(faces) + count
            vertices = np.concatenate([vertices, mids])
            faces = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                              np.stack([ab, bc, ca], 1)], axis=1).reshape(-1, 3)
        return Mesh(vertices, faces)

    def surfaces(self, names: list[str] | None = None, subdivisions: int = 0) -> list[Surface]:
        """Pieces as Surfaces (all by default); normal as built, boundary in the piece's frame."""
        mesh = self.mesh(subdivisions)
        areas = mesh.face_areas()
        out = []
        k = 4 ** subdivisions
        for name, frame, rings, faces in self.pieces:
            if names is not None and name not in names:
                continue
            faces = (faces[:, None] * k + np.arange(k)).ravel()
            out.append(Surface(id=len(out), frame=frame, area=float(areas[faces].sum()), face_indices=faces,
                               boundary=[[r.copy() for r in rings]]))
        return out

    def names(self) -> list[str]:
        return [p[0] for p in self.pieces]


def structure(builder: Builder) -> list[str]:
    """Names of the room pieces (floors, ceilings, walls), not furniture."""
    return [n for n in builder.names() if any(t in n for t in (".floor", ".ceiling", ".wall"))]
