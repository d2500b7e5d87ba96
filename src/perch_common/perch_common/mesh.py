"""Triangle mesh model, validation and file I/O (PLY/OBJ/GLB/STL)."""

from __future__ import annotations

import copy
import logging
import re
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

T = TypeVar("T")
FACE_BLOCK = 1 << 15   # faces per block of a per-face pass over a large mesh: its temporaries stay in cache
# How per-face and per-vertex keys are sorted where only the sorted values count: numpy's timsort takes
# the runs a mesh's face order leaves in its keys (a building's 6.9 M edge keys: 0.05 s against
# quicksort's 0.46; four real scans' 1.2-6x faster); on keys in random order it sorts ~17 % slower (argsorts alike).
ORDERED_SORT = "stable"
_BUILDING = "building"   # Mesh._cache keys (_BUILDING, key) hold the lock of a derived value's build
_BUILD_LOCKS_LOCK = threading.Lock()


class _BuildLock:
    """The lock of one derived value's build; a pickled mesh gets a fresh one (locks do not pickle)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()

    def __enter__(self) -> None:
        self._lock.acquire()

    def __exit__(self, *exc) -> None:
        self._lock.release()

    def __reduce__(self):
        return _BuildLock, ()


class MeshError(ValueError):
    """A mesh that cannot be used, with a message saying why and what to do."""


def column_bounds(points: np.ndarray) -> np.ndarray:
    """(2,C) per-column min and max of (N,C) points; column by column, ~20x faster than min(axis=0) on (N,3)."""
    points = np.asarray(points)
    columns = [points[:, i] for i in range(points.shape[1])]
    return np.array([[c.min() for c in columns], [c.max() for c in columns]])


@dataclass
class Mesh:
    """Vertices (V,3) float64 metres, faces (F,3) int64, optional per-vertex data."""

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None   # (V,3) uint8
    vertex_normals: np.ndarray | None = None  # (V,3) float
    frame_id: str = "map"
    # (K, 8) camera views the mesh was observed from (perch_common.viewpoints), or None (a bare mesh)
    viewpoints: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if self.vertex_colors is not None:
            self.vertex_colors = np.asarray(self.vertex_colors, dtype=np.uint8).reshape(-1, 3)
        if self.vertex_normals is not None:
            self.vertex_normals = np.asarray(self.vertex_normals, dtype=np.float64).reshape(-1, 3)
        if self.viewpoints is not None:
            from perch_common.viewpoints import VIEWPOINT_COLUMNS

            self.viewpoints = np.asarray(self.viewpoints, dtype=np.float64).reshape(-1, VIEWPOINT_COLUMNS)

    @property
    def num_faces(self) -> int:
        """Number of triangles."""
        return int(self.faces.shape[0])

    @property
    def num_vertices(self) -> int:
        """Number of vertices."""
        return int(self.vertices.shape[0])

    def triangles(self, faces: np.ndarray | None = None) -> np.ndarray:
        """(F,3,3) corner coordinates (of the faces indexed or masked by `faces` only: a surface's few
        faces of a building cost a gather of those, not of every face)."""
        return self.vertices[self.faces if faces is None else self.faces[faces]]

    def derived(self, key: str, build: Callable[[], T]) -> T:
        """Data derived from this mesh, built on first use and kept with it: every copy a request
        gets of a held mesh shares it (see mesh_cache), so stages in one process build it once. A
        caller asking while another thread builds it waits for that build (mesh_cache.prepare builds
        a held mesh's data in the background while stages run)."""
        if key in self._cache:
            return self._cache[key]
        with _BUILD_LOCKS_LOCK:   # the lock lives in the shared dict: copies of the mesh share it too
            lock = self._cache.setdefault((_BUILDING, key), _BuildLock())
        with lock:
            if key not in self._cache:
                self._cache[key] = build()
        return self._cache[key]

    def _cross(self) -> np.ndarray:
        if "cross" not in self._cache:
            # np.cross's arithmetic written out: the same numbers at half the time on 2M faces; block
            # by block, so that the corner copies stay in cache (0.26 -> 0.11 s on 2.3M faces).
            cross = np.empty((self.num_faces, 3), self.vertices.dtype)
            for start in range(0, self.num_faces, FACE_BLOCK):
                faces = self.faces[start:start + FACE_BLOCK]
                first = np.take(self.vertices, faces[:, 0], axis=0)
                u = np.take(self.vertices, faces[:, 1], axis=0) - first
                v = np.take(self.vertices, faces[:, 2], axis=0) - first
                out = cross[start:start + FACE_BLOCK]
                out[:, 0] = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
                out[:, 1] = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
                out[:, 2] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
            self._cache["cross"] = cross
        return self._cache["cross"]

    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas (m^2)."""
        # 0.5 * np.linalg.norm(cross, axis=1) written out (it sums (x^2 + y^2) + z^2: the same numbers),
        # block by block: 4x faster on 2M faces.
        cross = self._cross()
        areas = np.empty(len(cross), cross.dtype if cross.dtype.kind == "f" else np.float64)
        for start in range(0, len(cross), FACE_BLOCK):
            c, out = cross[start:start + FACE_BLOCK], areas[start:start + FACE_BLOCK]
            np.multiply(c[:, 0], c[:, 0], out=out)
            out += c[:, 1] * c[:, 1]
            out += c[:, 2] * c[:, 2]
        np.sqrt(areas, out=areas)
        areas *= 0.5
        return areas

    def face_normals(self) -> np.ndarray:
        """Unit normals by right-hand winding; zero for degenerate faces."""
        c = self._cross()
        n = np.linalg.norm(c, axis=1, keepdims=True)
        return np.divide(c, n, out=np.zeros_like(c), where=n > 0)

    def face_centroids(self) -> np.ndarray:
        """(F,3) triangle centroids."""
        # triangles().mean(axis=1)'s arithmetic ((a + b) + c) / 3, bit for bit, without its (F,3,3)
        # gather and strided reduction: half the time (0.32 -> 0.17 s on a 2.3 M-face building).
        corners = self.faces.T
        centroids = self.vertices[corners[0]]
        centroids += self.vertices[corners[1]]
        centroids += self.vertices[corners[2]]
        centroids /= 3
        return centroids

    def face_colors(self, which: np.ndarray | None = None) -> np.ndarray | None:
        """(F,3) mean vertex colour in [0,1] of every face (or of the faces `which` indexes), or None
        without colours."""
        if self.vertex_colors is None:
            return None
        faces = self.faces if which is None else self.faces[which]
        return self.vertex_colors[faces].astype(np.float64).mean(axis=1) / 255.0

    def face_color_table(self) -> np.ndarray | None:
        """(F,3) float32 mean vertex colour in [0,1] of every face (face_colors to float32 rounding),
        computed once and kept with the mesh (12 B a face): renderers look it up for every pixel of
        every picture. Read-only, as it is shared. None without colours."""
        if self.vertex_colors is None:
            return None

        def build() -> np.ndarray:
            # Corner by corner in uint16 (no overflow: 3 x 255): half the time of a (F,3,3) gather.
            colours = self.vertex_colors.astype(np.uint16)
            total = colours[self.faces[:, 0]] + colours[self.faces[:, 1]] + colours[self.faces[:, 2]]
            table = total.astype(np.float32) / np.float32(3 * 255)
            table.flags.writeable = False
            return table

        return self.derived("face_color_table", build)

    def bounds(self) -> np.ndarray:
        """(2,3) min and max corner."""
        if self.num_vertices == 0:
            return np.zeros((2, 3))
        return column_bounds(self.vertices)

    def submesh(self, face_mask_or_indices: np.ndarray) -> "Mesh":
        """The given faces with only the vertices they use, colours kept."""
        faces = self.faces[face_mask_or_indices]
        # A vertex mask and its running count, not np.unique's sort (4x faster, the same order).
        used = np.zeros(self.num_vertices, bool)
        used[faces] = True
        return Mesh(
            vertices=self.vertices[used],
            faces=(np.cumsum(used) - 1)[faces],
            vertex_colors=None if self.vertex_colors is None else self.vertex_colors[used],
            vertex_normals=None if self.vertex_normals is None else self.vertex_normals[used],
            frame_id=self.frame_id,
            viewpoints=self.viewpoints,   # what observed the whole mesh observed its parts
        )

    def transformed(self, matrix: np.ndarray) -> "Mesh":
        """Copy under a 4x4 rigid transform."""
        r, t = matrix[:3, :3], matrix[:3, 3]
        normals = None if self.vertex_normals is None else self.vertex_normals @ r.T
        views = None
        if self.viewpoints is not None:
            from perch_common.viewpoints import transform_viewpoints

            views = transform_viewpoints(self.viewpoints, matrix)
        return replace(self, vertices=self.vertices @ r.T + t, vertex_normals=normals, viewpoints=views, _cache={})

    def with_viewpoints_of(self, source: "Mesh") -> "Mesh":
        """This mesh carrying `source`'s viewpoints (a stage's output built from `source` in its frame);
        self when source has none."""
        if source.viewpoints is None or self.viewpoints is source.viewpoints:
            return self
        out = copy.copy(self)   # the arrays and the derived data stay shared
        out.viewpoints = source.viewpoints
        return out


@dataclass
class MeshProblems:
    """What `inspect_mesh` found; fatal problems make a mesh unusable."""

    fatal: list[str]
    warnings: list[str]
    degenerate_faces: int = 0
    duplicate_faces: int = 0


def inspect_mesh(mesh: Mesh, area_epsilon: float = 1e-12, warnings: bool = True) -> MeshProblems:
    """Fatal problems (unusable mesh) and, with `warnings`, degenerate and duplicate face counts.

    The duplicate census sorts every face (about 1 s per million faces): skip it when only
    usability matters.
    """
    fatal: list[str] = []
    census, warnings = warnings, []
    if mesh.num_faces == 0 or mesh.num_vertices == 0:
        fatal.append(f"mesh is empty ({mesh.num_vertices} vertices, {mesh.num_faces} faces)")
        return MeshProblems(fatal, warnings)
    if not np.isfinite(mesh.vertices).all():  # per-row detail only when something is wrong
        bad_vertices = ~np.isfinite(mesh.vertices).all(axis=1)
        first = int(np.flatnonzero(bad_vertices)[0])
        valid = (mesh.faces >= 0) & (mesh.faces < mesh.num_vertices)
        using = int((bad_vertices[np.where(valid, mesh.faces, 0)] & valid).any(axis=1).sum())
        fatal.append(f"{int(bad_vertices.sum())} vertices are NaN or infinite (first: vertex {first})"
                     + (f", used by {using} face{'s' if using > 1 else ''}: remove those faces, or export the "
                        "scan again without its invalid points" if using else ", used by no face: leave them out"))
    if mesh.faces.min() < 0 or mesh.faces.max() >= mesh.num_vertices:
        out_of_range = (mesh.faces < 0) | (mesh.faces >= mesh.num_vertices)
        face = int(np.flatnonzero(out_of_range.any(axis=1))[0])
        fatal.append(
            f"{int(out_of_range.any(axis=1).sum())} faces index vertices outside 0..{mesh.num_vertices - 1}"
            f" (first: face {face} = {mesh.faces[face].tolist()})")
    if mesh.vertex_colors is not None and len(mesh.vertex_colors) != mesh.num_vertices:
        fatal.append(f"{len(mesh.vertex_colors)} vertex colours for {mesh.num_vertices} vertices")
    if mesh.vertex_normals is not None and len(mesh.vertex_normals) != mesh.num_vertices:
        fatal.append(f"{len(mesh.vertex_normals)} vertex normals for {mesh.num_vertices} vertices")
    if fatal:
        return MeshProblems(fatal, warnings)
    degenerate = int((mesh.face_areas() <= area_epsilon).sum())
    if degenerate == mesh.num_faces:
        fatal.append("every face is degenerate (zero area)")
    lo, hi = mesh.bounds()
    far = far_problem(lo, hi)
    if far:
        fatal.append(far)
    if not census:
        return MeshProblems(fatal, warnings, degenerate)
    if degenerate:
        warnings.append(f"{degenerate} degenerate (zero-area) faces")
    units = scale_problem(float(np.max(hi - lo)))
    if units:
        warnings.append(units)
    # Rows as opaque bytes: unique on a 1-D view is much faster than unique(axis=0).
    rows = np.ascontiguousarray(np.sort(mesh.faces, axis=1)).view(np.dtype((np.void, 24))).ravel()
    duplicates = mesh.num_faces - len(np.unique(rows))
    if duplicates:
        warnings.append(f"{duplicates} duplicate faces")
    return MeshProblems(fatal, warnings, degenerate, duplicates)


# An indoor space larger than this along any axis was almost surely modelled in another unit (FILE_UNITS).
MAX_PLAUSIBLE_EXTENT = 200.0   # m
MIN_PLAUSIBLE_EXTENT = 1.5     # m: a scan smaller than this is no space a drone perches in
TYPICAL_EXTENT = 8.0           # m: a room's scan; the unit giving the nearest size is named first
FILE_UNITS = (("millimetres", "0.001"), ("centimetres", "0.01"), ("inches", "0.0254"), ("feet", "0.3048"))


MAX_COORDINATE = 10_000.0      # m: nothing Perch plans for lies 10 km from the origin


def far_problem(lo: np.ndarray, hi: np.ndarray, what: str = "mesh") -> str | None:
    """A message when a space of plausible size lies beyond MAX_COORDINATE of its origin (georeferenced
    coordinates: UTM, a site grid), naming the --shift that brings it near; else None. Perch's messages
    and ray casts carry float32 coordinates, whose steps are half a metre 5000 km out."""
    far = float(np.max(np.abs(np.concatenate([lo, hi]))))
    extent = float(np.max(hi - lo))
    if not np.isfinite(far) or far <= MAX_COORDINATE or extent > MAX_PLAUSIBLE_EXTENT:
        return None   # near, or a unit problem (scale_problem names it)
    shift = -np.round((np.asarray(lo) + np.asarray(hi)) / 2, -1) + 0.0   # whole tens of metres (no -0)
    step = float(np.spacing(np.float32(far)))
    return (f"{what} lies {far / 1000:,.1f} km from its origin but is only {extent:,.0f} m across: georeferenced "
            f"coordinates (UTM, a site grid)? Perch plans within {MAX_COORDINATE / 1000:g} km of the origin (its "
            f"messages carry float32 coordinates: {step:g} m steps out there); shift it near the origin "
            f"(--shift={','.join(f'{v:.0f}' for v in shift)}; the outputs are then in the shifted frame)")


STORED_STEP_LIMIT = 0.01   # m: a file holding positions no finer than this cannot show a perch's flatness


def stored_precision_problem(vertices: np.ndarray, scale: float = 1.0) -> str | None:
    """A message when every coordinate a file holds (`vertices`, as read, before `scale`) is a float32
    value and float32 steps that far from the origin are coarser than STORED_STEP_LIMIT (after `scale`):
    the geometry was rounded when the file was written (a georeferenced mesh exported in single
    precision: half-metre steps 5000 km out), which no shift undoes; else None."""
    vertices = np.asarray(vertices)
    if not vertices.size:
        return None
    far = float(np.max(np.abs(vertices)))
    step = float(np.spacing(np.float32(far))) * scale if np.isfinite(far) else 0.0
    if step <= STORED_STEP_LIMIT:   # near the origin (every mesh Perch meets): no float32 check needed
        return None
    if not np.array_equal(vertices.astype(np.float32), vertices):
        return None   # finer values than float32 holds: written in double precision (or as text)
    return (f"every coordinate in the file is a single-precision (float32) number, and {far * scale / 1000:,.1f} km "
            f"from the origin those hold positions only to {step:g} m steps: the geometry was rounded when the "
            "file was written, and no --shift restores it; export it again in double precision (PLY 'property "
            "double', an OBJ with every decimal) or moved near the origin first (e.g. CloudCompare's global shift)")


def scale_problem(extent: float, what: str = "mesh") -> str | None:
    """A message when a space `extent` metres across cannot be in metres, else None. It names every
    unit that gives a plausible indoor size (MIN_PLAUSIBLE_EXTENT to MAX_PLAUSIBLE_EXTENT m), the one
    nearest a typical scan's size first: the size alone cannot tell a room in centimetres from a
    larger one in inches, and the user knows what the exporter wrote."""
    if not np.isfinite(extent) or extent <= MAX_PLAUSIBLE_EXTENT:
        return None
    units = [(name, factor, extent * float(factor)) for name, factor in FILE_UNITS
             if MIN_PLAUSIBLE_EXTENT <= extent * float(factor) <= MAX_PLAUSIBLE_EXTENT]
    units.sort(key=lambda unit: abs(np.log(unit[2] / TYPICAL_EXTENT)))
    if not units:  # beyond every unit's plausible size: the smallest unit, as before
        units = [(FILE_UNITS[0][0], FILE_UNITS[0][1], extent * float(FILE_UNITS[0][1]))]
    (name, factor, size), others = units[0], units[1:]
    alternatives = "".join(f", or {other} ({other_size:.3g} m: --scale {other_factor})"
                           for other, other_factor, other_size in others)
    return (f"{what} is {extent:,.0f} m across, which suggests it is in {name} ({size:.3g} m across: "
            f"--scale {factor}){alternatives}, not metres; rescale it by the unit it was exported in "
            f"(--scale, or multiply its coordinates by that factor)")


FEET_HEIGHT = 6.0           # m: a space at least this tall ...
FEET_FURNITURE = 1.3        # m: ... whose furniture tops stand (median) this high is likely in feet (0.3048)
FURNITURE_MIN_AREA = 1.0    # m^2 of furniture tops for their height to say anything
FLOOR_LEVEL_SHARE = 0.25    # of the floor's area: an upward level this large is a floor (a storey's), not furniture


def feet_problem(mesh: Mesh, up: np.ndarray, what: str = "mesh") -> str | None:
    """A message when `mesh` (up along `up`) looks like a room in feet read as metres, else None.

    Its size cannot tell (a room in feet is 8-12 m across and 8-10 m tall, a hall's size), but furniture
    can: tables, seats and beds stand 0.4-1 m high in every room, and in feet 1.3-3.3 m. Up-facing
    horizontal faces between 0.25 m above the floor and half the height, levels as large as a quarter
    of the floor left out (a storey's floor, from which the tops above it are measured), stand
    (area-weighted median) FEET_FURNITURE or more high
    in a space FEET_HEIGHT or more tall only when read in the wrong unit (the shared real scans: 0.3-0.8 m,
    one 1.7 m in a 3.5 m room; in feet 1.6-2.6 m in 7.9-10.4 m)."""
    from perch_common.up_axis import height_levels, in_levels

    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    # Each face's centroid height from its corners' heights: three gathers of one float each instead of
    # three points' (the floats of face_centroids() @ up to the last bit or two; a given building's
    # 2.3 M faces 0.17 -> 0.044 s, before every mission).
    corner = mesh.vertices @ up
    height = corner[mesh.faces[:, 0]]
    height += corner[mesh.faces[:, 1]]
    height += corner[mesh.faces[:, 2]]
    height /= 3
    floor, ceiling = np.percentile(height, [1, 99])
    tall = float(ceiling - floor)
    if tall < FEET_HEIGHT:
        return None
    areas = mesh.face_areas()
    facing_up = mesh.face_normals() @ up > np.cos(np.radians(10.0))
    at_floor = float(areas[facing_up & (height <= floor + 0.05 * tall)].sum())
    band = facing_up & (height > floor + 0.25) & (height < floor + 0.5 * tall)
    edges, levels = height_levels(height, areas, band, floor, floor + 0.5 * tall, 0.1)
    slab = levels >= FLOOR_LEVEL_SHARE * max(at_floor, 1e-9)
    band &= ~in_levels(slab, height, edges)
    if float(areas[band].sum()) < FURNITURE_MIN_AREA:
        return None
    # Each top's height above the floor it stands on: the ground floor or a storey's below it.
    floors = np.concatenate([[floor], edges[:-1][slab]])
    above = height[band] - floors[np.searchsorted(floors, height[band], side="right") - 1]
    order = np.argsort(above)
    cumulative = np.cumsum(areas[band][order])
    median = float(above[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
    if median < FEET_FURNITURE:
        return None
    return (f"{what} is {tall:.1f} m tall and its furniture tops stand {median:.1f} m above its floor (tables and "
            f"seats stand 0.4-1 m high), which suggests it is in feet ({tall * 0.3048:.1f} m tall: --scale 0.3048)")


def validate_mesh(mesh: Mesh, what: str = "mesh") -> Mesh:
    """Raise MeshError naming every fatal problem; return the mesh unchanged otherwise."""
    problems = inspect_mesh(mesh, warnings=False)
    if problems.fatal:
        raise MeshError(f"{what}: " + "; ".join(problems.fatal))
    return mesh


SUPPORTED_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")
WRITABLE_SUFFIXES = (".ply", ".obj", ".glb", ".stl", ".off")   # save_mesh (a .gltf needs its .bin beside it)
# Formats scans arrive in that Perch does not read, with what turns them into one it does.
_OTHER_FORMATS = {
    **dict.fromkeys((".usdz", ".usd", ".usda", ".usdc"), (
        "Universal Scene Description (Apple RoomPlan, Polycam, Scaniverse): export the scan as OBJ, GLB or PLY "
        "from the capture app, or convert it (Blender: File > Import > USD, then File > Export > glTF 2.0)")),
    **dict.fromkeys((".pcd", ".las", ".laz", ".e57", ".xyz", ".pts", ".ptx"), (
        "a point cloud format, and Perch needs a surface mesh: mesh it first (CloudCompare or Open3D: Poisson "
        "surface reconstruction, saved as PLY), or reconstruct the RGB-D frames with `perch reconstruct`")),
    **dict.fromkeys((".fbx", ".dae", ".3ds", ".3mf", ".blend", ".x3d", ".wrl"), (
        "export it as OBJ, GLB or PLY from the tool that wrote it (Blender imports this format)")),
}


def add_units_arguments(parser, what: str = "the mesh") -> None:
    """--scale and --shift, the load_mesh arguments of every command that reads a mesh file."""
    from perch_common.cli_types import positive_float, xyz

    parser.add_argument("--scale", type=positive_float, default=1.0,
                        help=f"multiply the coordinates of {what} by this (0.001 for a file in millimetres)")
    parser.add_argument("--shift", type=xyz, default=None, metavar="X,Y,Z",
                        help=f"add this (metres) to the coordinates of {what}, after --scale: georeferenced "
                             "coordinates (e.g. UTM) moved near the origin; outputs are in the shifted frame")


def load_mesh(path: str | Path, validate: bool = True, scale: float = 1.0,
              shift: tuple[float, float, float] | None = None) -> Mesh:
    """Load a triangle mesh (a scene file is flattened into one mesh); its coordinates become
    file * `scale` + `shift` (`scale` 0.001 for a file in millimetres; `shift`, in metres, moves
    georeferenced coordinates near the origin, as CloudCompare's global shift)."""
    import trimesh

    path = Path(path)
    if path.is_dir():
        raise MeshError(f"{path}: is a folder, not a mesh file")
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        fix = _OTHER_FORMATS.get(path.suffix.lower(), "")
        raise MeshError(f"{path}: unsupported format '{path.suffix}' (use one of {', '.join(SUPPORTED_SUFFIXES)})"
                        + (f": {fix}" if fix else ""))
    if not (np.isfinite(scale) and scale > 0):
        raise MeshError(f"{path}: scale must be a finite number > 0, got {scale}")
    offset = np.zeros(3) if shift is None else np.asarray(shift, np.float64)
    if offset.shape != (3,) or not np.isfinite(offset).all():
        raise MeshError(f"{path}: shift must be three finite numbers, got {shift}")
    gltf = _gltf_problem(path)
    if gltf:
        raise MeshError(f"{path}: {gltf}")
    try:
        loaded = _load_single_mesh(path) or _load_obj_with_relative_indices(path) or \
            trimesh.load(path, process=False, force="mesh")
    except FileNotFoundError as exc:  # a .gltf's buffers (.bin) are files of their own
        raise MeshError(f"{path}: refers to {Path(exc.filename or str(exc)).name}, which is not beside it: copy the "
                        "glTF's .bin (and texture) files into its folder, or export one GLB file instead") from exc
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshError(f"{path}: cannot be read as a mesh: the file is truncated or corrupt "
                        f"({type(exc).__name__}: {exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{path}: holds no triangle mesh")
    refuse_truncated(path, len(loaded.vertices), len(loaded.faces))
    if len(loaded.faces) == 0:
        points = len(loaded.vertices) or _point_count(path)
        if points:
            raise MeshError(f"{path}: holds {points} points but no faces (a point cloud, not a mesh); mesh it "
                            "first, e.g. reconstruct it from the RGB-D frames with `perch reconstruct`")
        size = path.stat().st_size
        if size > 200:   # more than an empty file's header: something is there, and it is not geometry
            raise MeshError(f"{path}: no vertex or face could be read from its {size:,} bytes: not a mesh in the "
                            f"{path.suffix.lower()} format (another format under this name?)")
    from perch_common.viewpoints import moved_viewpoints, read_viewpoints_beside

    views = read_viewpoints_beside(path, np.asarray(loaded.vertices), np.asarray(loaded.faces))
    vertices, faces, kept = _without_unused_nonfinite(np.asarray(loaded.vertices, np.float64),
                                                      np.asarray(loaded.faces), path)
    stored = stored_precision_problem(vertices, scale)
    if stored:
        raise MeshError(f"{path}: {stored}")
    colors = _vertex_colors(loaded, path)
    mesh = Mesh(vertices * scale + offset, faces, colors if colors is None or kept is None else colors[kept],
                viewpoints=None if views is None else moved_viewpoints(views, scale, offset))
    return validate_mesh(mesh, str(path)) if validate else mesh


def _without_unused_nonfinite(vertices: np.ndarray, faces: np.ndarray,
                              path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The mesh without vertices whose coordinates are NaN or infinite and that no face uses (depth-camera
    exports keep one per invalid pixel), faces renumbered, and the kept vertices' mask (None: all kept).
    Such vertices are no geometry: they are left out with a warning. Any other case is returned as
    it is (validation names non-finite vertices that faces use, and indices out of range)."""
    bad = ~np.isfinite(vertices).all(axis=1)
    if not bad.any() or (len(faces) and (faces.min() < 0 or faces.max() >= len(vertices))):
        return vertices, faces, None
    if len(faces) and bad[faces].any():
        return vertices, faces, None
    kept = ~bad
    renumbered = np.cumsum(kept) - 1
    logging.getLogger("perch.mesh").warning(
        "%s: %d vertices with NaN or infinite coordinates, used by no face, are left out", path, int(bad.sum()))
    return vertices[kept], renumbered[faces], kept


def _vertex_colors(loaded, path: Path) -> np.ndarray | None:
    """(N, 3) uint8 vertex colours of a loaded Trimesh (sampled from its texture when it has one), or
    None. Colours are only shown (console, recordings): a texture that cannot be sampled (its image
    missing beside the file) leaves the mesh uncoloured, with a warning, and the geometry is read."""
    visual = getattr(loaded, "visual", None)
    kind = getattr(visual, "kind", None)
    try:
        if kind == "vertex":
            colors = np.asarray(visual.vertex_colors)
        elif kind == "texture":
            colors = np.asarray(visual.to_color().vertex_colors)
        else:
            return None
    except Exception as exc:  # trimesh's texture sampling raises many types for a missing or odd image
        colors, reason = None, f"{type(exc).__name__}: {exc}"
    else:
        reason = f"colours of shape {colors.shape} for {len(loaded.vertices)} vertices"
    if colors is not None and colors.ndim == 2 and colors.shape[0] == len(loaded.vertices) and colors.shape[1] >= 3:
        return np.ascontiguousarray(colors[:, :3], np.uint8)
    logging.getLogger("perch.mesh").warning(
        "%s: its %s colours cannot be read (%s; a texture image missing beside the file?); the mesh is read "
        "without colours", path, "texture" if kind == "texture" else "vertex", reason)
    return None


# glTF extensions a file may require that change its geometry and that trimesh cannot decode: the
# file would load with its vertices unread (meshopt) or its instances missing.
_GLTF_UNREADABLE = {
    "EXT_meshopt_compression": "meshopt compression",
    "KHR_meshopt_compression": "meshopt compression",
    "EXT_mesh_gpu_instancing": "GPU instancing (copies of a mesh placed by the viewer)",
}


def _gltf_problem(path: Path) -> str:
    """Why a glTF/GLB file cannot be read whole (an extension it requires that changes its geometry
    and is not decoded here), or "". Draco (KHR_draco_mesh_compression, through DracoPy) and
    quantized positions (KHR_mesh_quantization) are read."""
    import json
    import struct

    suffix = path.suffix.lower()
    if suffix not in (".glb", ".gltf"):
        return ""
    try:
        with open(path, "rb") as stream:
            if suffix == ".glb":
                head = stream.read(20)
                if len(head) < 20 or head[:4] != b"glTF":
                    return ""   # the loader words what is wrong
                length, kind = struct.unpack("<II", head[12:20])
                if kind != 0x4E4F534A:   # the first chunk is JSON
                    return ""
                header = json.loads(stream.read(length))
            else:
                header = json.load(stream)
    except (OSError, ValueError):
        return ""
    required = header.get("extensionsRequired", []) if isinstance(header, dict) else []
    unreadable = [f"{name} ({_GLTF_UNREADABLE[name]})" for name in required if name in _GLTF_UNREADABLE]
    if not unreadable:
        return ""
    return (f"requires the glTF extension {', '.join(unreadable)}, which Perch cannot decode: export it again "
            "without it (uncompressed or with Draco compression, which Perch reads), or as OBJ or PLY")


def _load_single_mesh(path: Path):
    """A PLY, STL or OFF file holding one triangle mesh, read by trimesh's format reader straight into a
    Trimesh; None for anything else (the caller's trimesh.load decides, and words its errors). trimesh.load
    builds a scene and copies it into one mesh, deriving face colours on the way: 7 s for a 7.2 M-face
    PLY whose reading takes 0.6 s."""
    import trimesh
    from trimesh.exchange.load import mesh_loaders

    kind = path.suffix.lower().lstrip(".")
    if kind not in ("ply", "stl", "off"):
        return None
    try:
        with open(path, "rb") as stream:
            read = mesh_loaders[kind](stream, file_type=kind)
    except Exception:   # a corrupt file: trimesh.load reads it again and the caller says what is wrong
        return None
    if not isinstance(read, dict) or "geometry" in read or len(read.get("faces", ())) == 0:
        return None
    read.pop("metadata", None)
    return trimesh.Trimesh(**read, process=False)


_OBJ_RECORDS = (b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p")
_OBJ_RELATIVE_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[\s/])-[0-9]", re.MULTILINE)


def _load_obj_with_relative_indices(path: Path):
    """An OBJ whose faces use relative indices (-1: the latest vertex read so far, as the OBJ specification
    says), read with each made absolute; None for any other file. trimesh counts them from the end of the
    whole file instead: an OBJ that writes each face after its own vertices ('f -3 -2 -1') became a 4 mm blob
    of the file's last three vertices."""
    import io

    import trimesh

    if path.suffix.lower() != ".obj":
        return None
    data = path.read_bytes()
    if not _OBJ_RELATIVE_INDEX.search(data):
        return None
    counts = {b"v": 0, b"vt": 0, b"vn": 0}
    out = []
    for line in data.splitlines(keepends=True):
        words = line.split()
        if words and words[0] in counts:
            counts[words[0]] += 1
        elif words and words[0] == b"f":
            corners = []
            for word in words[1:]:
                parts = word.split(b"/")
                for k, (part, kind) in enumerate(zip(parts, (b"v", b"vt", b"vn"))):
                    if part.startswith(b"-"):
                        parts[k] = str(counts[kind] + 1 + int(part)).encode()
                corners.append(b"/".join(parts))
            line = b"f " + b" ".join(corners) + b"\n"
        out.append(line)
    return trimesh.load(io.BytesIO(b"".join(out)), file_type="obj", process=False, force="mesh",
                        resolver=trimesh.resolvers.FilePathResolver(str(path)))


def refuse_truncated(path: Path, vertices: int, faces: int) -> None:
    """Raise MeshError for a mesh file whose body was cut short (loaders read such a file silently,
    and a mission would plan on part of the room): a PLY with fewer elements than its header
    declares, an OBJ whose last line is a data record cut mid-line."""
    suffix = path.suffix.lower()
    if suffix == ".ply":
        with open(path, "rb") as stream:
            head = stream.read(65536)
        end = head.find(b"end_header")
        declared = {}
        for line in head[:end if end >= 0 else 0].splitlines():
            words = line.split()
            if len(words) == 3 and words[0] == b"element" and words[1] in (b"vertex", b"face") and words[2].isdigit():
                declared[words[1].decode()] = int(words[2])
        if not declared.get("face"):
            return   # a point cloud: said as such by the caller
        # Polygons load as several triangles (more faces than declared), never as fewer.
        for name, found in (("vertex", vertices), ("face", faces)):
            if name in declared and found < declared[name]:
                raise MeshError(f"{path}: holds {found:,} of the {declared[name]:,} {name} elements its header "
                                "declares: the file is truncated (cut short); copy or export it again")
    elif suffix == ".obj":
        size = path.stat().st_size
        with open(path, "rb") as stream:
            stream.seek(max(0, size - 4096))
            tail = stream.read()
        if not tail or tail.endswith((b"\n", b"\r")):
            return
        last = tail.splitlines()[-1].strip()
        if last.split(b" ", 1)[0] in _OBJ_RECORDS:
            shown = last[:40].decode(errors="replace")
            raise MeshError(f"{path}: ends in the middle of a line ('{shown}'), as a file cut short does: it is "
                            "probably truncated and Perch will not plan on part of a room. Copy or export it "
                            "again (if it is complete, end it with a line break)")


def _point_count(path: Path) -> int:
    """Points in a file trimesh reads as a point cloud (0 when it is not one)."""
    import trimesh

    try:
        loaded = trimesh.load(path, process=False)
    except Exception:  # already known to hold no faces; any failure just means "not a point cloud"
        return 0
    return len(loaded.vertices) if isinstance(loaded, trimesh.PointCloud) else 0


def mesh_output(path: str | Path | None, option: str = "-o") -> Path | None:
    """`path` when a mesh can be written there (a format save_mesh writes, not an existing folder), checked
    before a command's work; MeshError naming the option and the formats otherwise (None passes)."""
    if path is None:
        return None
    path = Path(path)
    if path.is_dir():
        raise MeshError(f"{option} {path}: is a folder; give a mesh file name (e.g. {path / 'mesh.ply'})")
    if path.suffix.lower() not in WRITABLE_SUFFIXES:
        raise MeshError(f"{option} {path}: not a mesh format Perch writes; end the name in one of "
                        f"{', '.join(WRITABLE_SUFFIXES)}")
    return path


def save_mesh(path: str | Path, mesh: Mesh, face_colors: np.ndarray | None = None) -> Path:
    """Write a mesh (atomically); face_colors (F,3) uint8 overrides vertex colours (for labelled output)."""
    import trimesh

    from perch_common.outputs import atomic_path

    path = Path(path)
    out = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                          vertex_colors=None if face_colors is not None else mesh.vertex_colors,
                          face_colors=face_colors)
    with atomic_path(path) as temporary:   # a reader never sees half a mesh; a failed write keeps the old one
        out.export(temporary)
    return path
