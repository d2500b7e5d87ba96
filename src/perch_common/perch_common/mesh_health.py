"""Mesh health: what makes a real-world mesh slow or wrong to plan on, counted, and repaired where it can be.

- Triangle soup: most faces share no vertex with another face (every corner stored per face), so
  no piece is bigger than one triangle until corners at the same place are welded.
- Duplicate faces: the same three corner positions more than once (in any order or winding).
- Inconsistent windings: two faces sharing an edge that run it in the same direction, i.e. one of
  them faces the other way (a surface whose normals flip from face to face).
- Needle slivers: triangles far longer than the mesh's typical edge and almost no wider (altitude
  below 1/1000 of the longest edge): they span empty space, block clearance tests and carry no
  surface worth a perch.

Everything is vectorised (numpy, scipy.sparse); about 0.3 s per 100k faces.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from perch_common.mesh import FACE_BLOCK, ORDERED_SORT, Mesh

NEEDLE_ASPECT = 1e-3        # altitude / longest edge below this: a sliver
NEEDLE_LENGTH = 10.0        # ... and longer than this many median edge lengths: a needle across space
SOUP_SHARE = 0.5            # more than this share of faces without a neighbour: a triangle soup
# More than this share of vertices used by no face: faces were lost (an OBJ cut at a line break keeps
# all its `v` lines and a part of its `f` lines). Real scans in the data: 0 % to 7.8 %.
UNREFERENCED_SHARE = 0.2


@dataclass
class MeshHealth:
    """Counts of what `inspect_health` found; `lines()` says each in words."""

    faces: int
    isolated_faces: int = 0          # faces sharing no edge with another (after welding coincident corners)
    duplicate_faces: int = 0
    inconsistent_edges: int = 0      # shared edges run the same way by both faces
    flipped_faces: int = 0           # faces to turn over for a consistent winding (per piece, the minority)
    needle_slivers: int = 0
    soup: bool = False               # most faces share no vertex index with another (before welding)
    vertices: int = 0                # in the file (an OBJ's `v` lines) or the mesh
    unreferenced_vertices: int = 0   # of those, used by no face
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        """One line per problem found (empty: healthy)."""
        out = []
        if self.soup:
            out.append(f"triangle soup: most of the {self.faces:,} faces share no vertex with another "
                       "(corners at the same place are separate vertices; the clean stage welds them)")
        if self.duplicate_faces:
            out.append(f"{self.duplicate_faces:,} duplicate faces (same corners as another face)")
        if self.flipped_faces:
            out.append(f"inconsistent windings: {self.flipped_faces:,} faces face the other way from their "
                       f"neighbours ({self.inconsistent_edges:,} shared edges run the same way)")
        if self.needle_slivers:
            out.append(f"{self.needle_slivers:,} needle slivers (triangles over {NEEDLE_LENGTH:g}x the median edge "
                       f"long and under 1/{1 / NEEDLE_ASPECT:g} of that wide)")
        line = unreferenced_line(self.unreferenced_vertices, self.vertices)
        if line:
            out.append(line)
        if self.isolated_faces > SOUP_SHARE * self.faces and not self.soup:
            out.append(f"{self.isolated_faces:,} of {self.faces:,} faces share no edge with another")
        return out + self.notes


def weld_positions(vertices: np.ndarray, faces: np.ndarray, distance: float) -> np.ndarray:
    """Faces re-indexed so that corners within `distance` (on a grid of that size) share one vertex."""
    if len(vertices) == 0:
        return faces
    key = np.floor((vertices - vertices.min(axis=0)) / max(distance, 1e-12)).astype(np.int64)
    span = key.max(axis=0) + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2.0 ** 62:   # one int64 per cell
        _, inverse = np.unique((key[:, 0] * span[1] + key[:, 1]) * span[2] + key[:, 2], return_inverse=True)
    else:
        _, inverse = np.unique(np.ascontiguousarray(key).view(np.dtype((np.void, 24))).ravel(), return_inverse=True)
    return inverse.ravel()[faces]


def _edge_keys(directed: np.ndarray, count: int) -> np.ndarray:
    """One int64 per undirected edge (its two vertex indices, smaller first)."""
    low, high = np.minimum(directed[:, 0], directed[:, 1]), np.maximum(directed[:, 0], directed[:, 1])
    return low.astype(np.int64) * count + high


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(E,2) directed edges (a->b as each face runs them) and the face of each."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    return directed, owner


def needle_mask(mesh: Mesh) -> np.ndarray:
    """Faces that are needle slivers (see NEEDLE_ASPECT, NEEDLE_LENGTH)."""
    if mesh.num_faces == 0:
        return np.zeros(0, bool)
    if _too_short_for_needles(mesh.vertices, mesh.faces):
        return np.zeros(mesh.num_faces, bool)
    lengths = _edge_lengths(mesh.vertices, mesh.faces)
    longest = np.maximum(np.maximum(lengths[:, 0], lengths[:, 1]), lengths[:, 2])   # max(axis=1), 5x faster
    typical = float(np.median(lengths, overwrite_input=True))
    # Only faces long enough to be needles need their width (most of a large mesh is not).
    needles = np.flatnonzero(longest > NEEDLE_LENGTH * typical)
    cross = Mesh(mesh.vertices, mesh.faces[needles]).face_areas() * 2.0
    altitude = cross / np.maximum(longest[needles], 1e-300)
    mask = np.zeros(mesh.num_faces, bool)
    mask[needles] = altitude < NEEDLE_ASPECT * longest[needles]
    return mask


def _too_short_for_needles(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether no edge is over NEEDLE_LENGTH x a lower bound of the median edge (then no face is a
    needle), in one pass that keeps no face-sized array: the bound is a sample's lower quartile,
    checked to lie at or below the median (no more edges than half shorter than it)."""
    sample = _edge_lengths(vertices, faces[::max(1, len(faces) // 4096)]).ravel()
    bound = np.partition(sample, len(sample) // 4)[len(sample) // 4]
    shorter, longest = 0, 0.0
    for start in range(0, len(faces), FACE_BLOCK):
        lengths = _edge_lengths(vertices, faces[start:start + FACE_BLOCK])
        shorter += int(np.count_nonzero(lengths < bound))
        longest = max(longest, float(lengths.max()))
    # the median is at least the ((3F - 1) // 2)-th shortest edge (from 0), which is >= bound
    return shorter <= (3 * len(faces) - 1) // 2 and longest <= NEEDLE_LENGTH * bound


def _edge_lengths(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,3) lengths |b - a|, |c - b|, |a - c| of every face, summed in np.linalg.norm's order (the same
    numbers). Block by block: on millions of faces whole-array corner copies cost more than the sums."""
    lengths = np.empty((len(faces), 3))
    for start in range(0, len(faces), FACE_BLOCK):
        block = faces[start:start + FACE_BLOCK]
        corner = [np.take(vertices, block[:, i], axis=0) for i in range(3)]
        out = lengths[start:start + FACE_BLOCK]
        for i in range(3):
            edge = corner[(i + 1) % 3] - corner[i]
            out[:, i] = edge[:, 0] * edge[:, 0] + edge[:, 1] * edge[:, 1] + edge[:, 2] * edge[:, 2]
    return np.sqrt(lengths, out=lengths)


def winding_flips(faces: np.ndarray, at_least: float = 0) -> tuple[np.ndarray, int]:
    """(faces to turn over so that every piece is wound consistently, shared edges run the same way);
    with `at_least`, no faces are chosen (only counted) unless more edges than that are inconsistent.

    Faces are joined across edges shared by exactly two faces; within each piece the winding of the
    majority is kept. A piece that cannot be wound consistently (a Moebius-like strip) keeps the
    first consistent winding a breadth-first walk finds.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    n = len(faces)
    flips = np.zeros(n, bool)
    if n == 0:
        return flips, 0
    inconsistent = _same_way_edges(faces)
    if not inconsistent or inconsistent <= at_least:
        return flips, inconsistent
    directed, owner = _edges(faces)
    # The two uses of each manifold edge (shared by exactly two faces), in the order of the edges' keys:
    # one sort of the keys (np.unique and a second sort of the shared edges cost twice as much).
    keys = _edge_keys(directed, int(faces.max()) + 1)
    order = np.argsort(keys)
    keys = keys[order]
    starts = np.flatnonzero(np.concatenate([[True], keys[1:] != keys[:-1]]))
    pairs = starts[np.diff(np.append(starts, len(keys))) == 2]
    first, second = np.minimum(order[pairs], order[pairs + 1]), np.maximum(order[pairs], order[pairs + 1])
    same_way = directed[first, 0] == directed[second, 0]     # both faces run the edge a->b: inconsistent
    fa, fb = owner[first], owner[second]
    # 1: consistent neighbours, 2: one of the two must turn over.
    relation = np.where(same_way, 2, 1).astype(np.int8)
    graph = coo_matrix((relation, (fa, fb)), shape=(n, n)).tocsr()
    count, label = connected_components(graph, directed=False)
    # One breadth-first walk over every piece: a virtual root (n) joined consistently to each piece's
    # first face; parity along the walk says which faces turn over relative to that face.
    roots = np.unique(label, return_index=True)[1]
    rows = np.concatenate([fa, np.full(len(roots), n)])
    cols = np.concatenate([fb, roots])
    values = np.concatenate([relation, np.ones(len(roots), np.int8)])
    forest = coo_matrix((values, (rows, cols)), shape=(n + 1, n + 1)).tocsr()
    forest = forest.maximum(forest.T).tocsr()
    walk, parent = breadth_first_order(forest, n, directed=False, return_predecessors=True)
    children = walk[1:]
    turn = np.asarray(forest[children, parent[children]]).ravel() == 2
    parity = np.zeros(n + 1, bool)
    parents = parent[children]
    for child, above, flip in zip(children.tolist(), parents.tolist(), turn.tolist()):
        parity[child] = parity[above] ^ flip   # parents come before their children in breadth-first order
    parity = parity[:n]
    turned = np.bincount(label, weights=parity, minlength=count)
    sizes = np.bincount(label, minlength=count)
    flips = parity ^ (2 * turned > sizes)[label]   # keep each piece's majority winding
    return flips, inconsistent


def _same_way_edges(faces: np.ndarray) -> int:
    """How many edges shared by exactly two faces both faces run the same way (winding_flips' count),
    from one sort of the directed edges: a consistent mesh has no directed edge twice, and then
    nothing else is needed; otherwise only the repeated ones are looked at."""
    count = int(faces.max()) + 1
    keys = np.empty(3 * len(faces), np.int64)   # a -> b as a * count + b, for (0,1), (1,2), (2,0)
    for i, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        part = keys[i * len(faces):(i + 1) * len(faces)]
        np.multiply(faces[:, a], count, out=part)
        part += faces[:, b]
    keys.sort(kind=ORDERED_SORT)
    repeated = np.flatnonzero(keys[1:] == keys[:-1])
    if not len(repeated):
        return 0
    # Edges run exactly twice one way: runs of two equal keys (not part of a longer run) ...
    longer = np.zeros(len(repeated), bool)
    gap = np.diff(repeated) == 1   # neighbouring repeats: a run of three or more
    longer[1:] |= gap
    longer[:-1] |= gap
    twice = keys[repeated[~longer]]
    a, b = twice // count, twice % count
    # ... and never the other way (an edge used by exactly two faces); a loop a -> a is its own reverse.
    reverse = b * count + a
    found = np.searchsorted(keys, reverse)
    found = np.minimum(found, len(keys) - 1)
    return int(((keys[found] != reverse) | (a == b)).sum())


def unreferenced_line(unreferenced: int, vertices: int) -> str:
    """The warning for a large share of vertices used by no face ('' below UNREFERENCED_SHARE)."""
    if not vertices or unreferenced <= UNREFERENCED_SHARE * vertices:
        return ""
    return (f"{unreferenced:,} of {vertices:,} vertices ({100 * unreferenced / vertices:.0f} %) are used by no "
            "face: the file may be cut short or faces lost")


def unreferenced_vertices(mesh: Mesh, path: str | Path | None = None) -> tuple[int, int]:
    """(vertices used by no face, vertices). For an OBJ file, counted in the file: its loader keeps only
    the vertices faces use, so a file that lost faces looks whole once loaded."""
    if path is not None and Path(path).suffix.lower() == ".obj":
        counted = obj_vertex_use(path)
        if counted is not None:
            return counted
    if mesh.num_vertices == 0:
        return 0, 0
    used = np.bincount(mesh.faces.ravel(), minlength=mesh.num_vertices) if mesh.num_faces else np.zeros(0)
    return int(mesh.num_vertices - np.count_nonzero(used[:mesh.num_vertices])), mesh.num_vertices


def obj_vertex_use(path: str | Path) -> tuple[int, int] | None:
    """(`v` lines no face uses, `v` lines) of an OBJ file; None when its faces use relative (negative)
    indices, whose vertex depends on the line's position."""
    import re

    data = Path(path).read_bytes()
    vertices = len(re.findall(rb"(?m)^[ \t]*v[ \t]", data))
    faces = re.findall(rb"(?m)^[ \t]*f[ \t]+([^\r\n#]*)", data)
    if not vertices:
        return 0, 0
    tokens = b" ".join(faces).split()
    try:
        indices = np.array([int(t.split(b"/", 1)[0]) for t in tokens], np.int64)
    except ValueError:   # a malformed face: the loader says what is wrong with the file
        return None
    if (indices < 0).any():
        return None
    used = np.unique(indices[(indices >= 1) & (indices <= vertices)])
    return vertices - len(used), vertices


def inspect_health(mesh: Mesh, weld_distance: float = 1e-5, path: str | Path | None = None) -> MeshHealth:
    """Count the problems of `mesh` (its arrays are not changed); `path`, the file it was loaded from,
    for what only the file shows (an OBJ's vertices no face uses)."""
    health = MeshHealth(mesh.num_faces)
    health.unreferenced_vertices, health.vertices = unreferenced_vertices(mesh, path)
    if mesh.num_faces == 0:
        return health
    faces = mesh.faces
    used = np.bincount(faces.ravel(), minlength=mesh.num_vertices)
    health.soup = mesh.num_faces > 1 and float((used[faces] == 1).all(axis=1).mean()) > SOUP_SHARE
    welded = weld_positions(mesh.vertices, faces, weld_distance)
    rows = np.ascontiguousarray(np.sort(welded, axis=1)).view(np.dtype((np.void, 24))).ravel()
    _, first = np.unique(rows, return_index=True)
    health.duplicate_faces = mesh.num_faces - len(first)
    keep = np.zeros(mesh.num_faces, bool)
    keep[first] = True
    proper = keep & (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])
    kept = welded[proper]
    directed, owner = _edges(kept)
    _, edge_id, counts = np.unique(_edge_keys(directed, int(welded.max()) + 1), return_inverse=True,
                                   return_counts=True)
    alone = np.bincount(owner[counts[edge_id.ravel()] > 1], minlength=len(kept)) == 0
    health.isolated_faces = int(alone.sum())
    flips, health.inconsistent_edges = winding_flips(kept)
    health.flipped_faces = int(flips.sum())
    health.needle_slivers = int(needle_mask(mesh).sum())
    return health
