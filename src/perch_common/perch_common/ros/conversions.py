"""numpy <-> perch_interfaces messages, through buffers (no per-element Python loops)."""

from __future__ import annotations

import array
import copy

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3

from perch_common.mesh import Mesh, MeshError
from perch_common.target import TargetVolume
from perch_common.transforms import pose_to_matrix, quaternion_from_matrix
from perch_common.types import (
    CameraPlacement,
    ExclusionZone,
    FilterRemoval,
    PerchEvidence,
    PerchRegion,
    PlaneFrame,
    Surface,
    SurfaceClass,
)
from perch_common.viewpoints import VIEWPOINT_COLUMNS, viewpoint_problem
from perch_interfaces import msg as pm

_TYPECODES = {np.float32: "f", np.float64: "d", np.uint32: "I", np.uint8: "B", np.int32: "i"}


def to_array(values: np.ndarray, dtype: type) -> array.array:
    """A numpy array as the array.array rclpy stores sequence fields in (one memcpy)."""
    out = array.array(_TYPECODES[dtype])
    out.frombytes(np.ascontiguousarray(values, dtype=dtype).tobytes())
    return out


def from_array(values, dtype: type, columns: int | None = None) -> np.ndarray:
    """A sequence field as a numpy array (zero-copy view for array.array), optionally (N, columns)."""
    arr = np.frombuffer(values, dtype=dtype) if len(values) else np.zeros(0, dtype)
    return arr.reshape(-1, columns) if columns else arr


# --- geometry -------------------------------------------------------------------------------

def point_msg(p: np.ndarray) -> Point:
    """geometry_msgs/Point of a 3-vector."""
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def vector_msg(v: np.ndarray) -> Vector3:
    """geometry_msgs/Vector3 of a 3-vector."""
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def xyz(m) -> np.ndarray:
    """Point or Vector3 as a numpy array."""
    return np.array([m.x, m.y, m.z], dtype=np.float64)


def pose_msg(matrix: np.ndarray) -> Pose:
    """geometry_msgs/Pose of a 4x4 rigid transform."""
    q = quaternion_from_matrix(matrix[:3, :3])
    return Pose(position=point_msg(matrix[:3, 3]), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def pose_matrix(pose: Pose) -> np.ndarray:
    """4x4 rigid transform of a geometry_msgs/Pose."""
    return pose_to_matrix(pose)


# --- mesh -----------------------------------------------------------------------------------

def mesh_to_msg(mesh: Mesh, stamp=None) -> pm.TriangleMesh:
    """perch_interfaces/TriangleMesh of a mesh (flat float32 vertices, uint32 faces, optional colours)."""
    msg = pm.TriangleMesh()
    msg.header.frame_id = mesh.frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.vertices = to_array(mesh.vertices, np.float32)
    msg.triangles = to_array(mesh.faces, np.uint32)
    if mesh.vertex_colors is not None:
        msg.vertex_colors = to_array(mesh.vertex_colors, np.uint8)
    if mesh.vertex_normals is not None:
        msg.vertex_normals = to_array(mesh.vertex_normals, np.float32)
    if mesh.viewpoints is not None:
        msg.viewpoints = to_array(mesh.viewpoints, np.float64)
    return msg


def mesh_from_msg(msg: pm.TriangleMesh, what: str = "mesh") -> Mesh:
    """The message's mesh; raises MeshError when its arrays are inconsistent."""
    n_v, n_t = len(msg.vertices), len(msg.triangles)
    if n_v % 3 or n_t % 3:
        raise MeshError(f"{what}: vertices ({n_v}) and triangles ({n_t}) must be multiples of 3")
    vertices = from_array(msg.vertices, np.float32, 3).astype(np.float64)
    colors = from_array(msg.vertex_colors, np.uint8, 3) if len(msg.vertex_colors) else None
    normals = from_array(msg.vertex_normals, np.float32, 3) if len(msg.vertex_normals) else None
    for name, arr in (("vertex_colors", colors), ("vertex_normals", normals)):
        if arr is not None and len(arr) != len(vertices):
            raise MeshError(f"{what}: {name} has {len(arr)} entries for {len(vertices)} vertices")
    views = None
    if len(msg.viewpoints):
        problem = viewpoint_problem(from_array(msg.viewpoints, np.float64))
        if problem:
            raise MeshError(f"{what}: {problem}")
        views = from_array(msg.viewpoints, np.float64, VIEWPOINT_COLUMNS)
    return Mesh(vertices, from_array(msg.triangles, np.uint32, 3).astype(np.int64),
                None if colors is None else colors.copy(), normals, frame_id=msg.header.frame_id or "map",
                viewpoints=views)


def msg_content_id(msg: pm.TriangleMesh) -> str:
    """The content id of a mesh message's arrays (as they travel), computed, not trusted."""
    from perch_common.mesh_cache import content_id

    return content_id(from_array(msg.vertices, np.float32), from_array(msg.triangles, np.uint32),
                      from_array(msg.vertex_colors, np.uint8), from_array(msg.vertex_normals, np.float32),
                      from_array(msg.viewpoints, np.float64))


def is_id_only(msg: pm.TriangleMesh) -> bool:
    """A mesh message that names a held mesh by content id instead of carrying arrays."""
    return bool(msg.content_id) and not len(msg.vertices) and not len(msg.triangles)


def id_only_msg(msg: pm.TriangleMesh) -> pm.TriangleMesh:
    """The same mesh by content id alone (header kept)."""
    return pm.TriangleMesh(header=msg.header, content_id=msg.content_id)


def _keep(msg: pm.TriangleMesh, what: str) -> Mesh:
    """Decode `msg`, freeze its arrays and keep it in this process's mesh cache under msg.content_id."""
    from perch_common.mesh_cache import PROCESS_CACHE

    mesh = mesh_from_msg(msg, what)
    for values in (mesh.vertices, mesh.faces, mesh.vertex_colors, mesh.vertex_normals, mesh.viewpoints):
        if values is not None:
            values.flags.writeable = False   # shared by every request naming it: never changed in place
    PROCESS_CACHE.put(msg.content_id, mesh)
    return mesh


def mesh_from_request(msg: pm.TriangleMesh, what: str = "mesh") -> Mesh:
    """A request's mesh: its arrays (kept in this process's cache under their id), or, for an
    id-only message, the held mesh; raises MeshNotCached when this process does not hold it.
    The returned arrays are read-only (shared with later requests)."""
    from perch_common.mesh_cache import PROCESS_CACHE, MeshNotCached

    if is_id_only(msg):
        mesh = PROCESS_CACHE.get(msg.content_id)
        if mesh is None:
            raise MeshNotCached(msg.content_id, what)
        mesh = copy.copy(mesh)   # its own frame_id; the (read-only) arrays stay shared
        mesh.frame_id = msg.header.frame_id or mesh.frame_id
        return mesh
    msg.content_id = msg_content_id(msg)
    return held_mesh(msg, hashed=True) or _keep(msg, what)


def held_mesh(msg: pm.TriangleMesh, hashed: bool = False) -> Mesh | None:
    """The mesh this process holds with the arrays of `msg` (which carry them), else None: the same
    numbers, sharing what the stages derived and keep with it (face data, its ray-cast BVH), where
    decoding the message starts from nothing. Only when the arrays hash to the message's id (3 ms
    on 100k faces; `hashed`: the caller has just set the id from them)."""
    from perch_common.mesh_cache import PROCESS_CACHE

    held = PROCESS_CACHE.get(msg.content_id) if msg.content_id else None
    if held is None or (not hashed and msg_content_id(msg) != msg.content_id):
        return None
    mesh = copy.copy(held)   # its own frame_id; the (read-only) arrays and the derived data stay shared
    mesh.frame_id = msg.header.frame_id or "map"   # as mesh_from_msg names it
    return mesh


def cached_mesh_to_msg(mesh: Mesh, stamp=None) -> pm.TriangleMesh:
    """mesh_to_msg with its content id, and kept in this process's mesh cache, for a reply whose
    mesh later requests (to this or another node in this process) may name by id."""
    from perch_common.mesh_cache import PROCESS_CACHE, prepare

    msg = mesh_to_msg(mesh, stamp)
    msg.content_id = msg_content_id(msg)
    kept = _keep(msg, "reply mesh")
    if msg.content_id in PROCESS_CACHE:   # the next stages here work on it: their data is built meanwhile
        prepare(kept)
    return msg


# --- planes and polygons -----------------------------------------------------------------------

def frame_to_msg(frame: PlaneFrame) -> pm.PlaneFrame:
    """perch_interfaces/PlaneFrame of a plane frame."""
    return pm.PlaneFrame(origin=point_msg(frame.origin), axis_u=vector_msg(frame.axis_u),
                         axis_v=vector_msg(frame.axis_v), normal=vector_msg(frame.normal))


def frame_from_msg(msg: pm.PlaneFrame) -> PlaneFrame:
    """Plane frame of a perch_interfaces/PlaneFrame."""
    return PlaneFrame(xyz(msg.origin), xyz(msg.axis_u), xyz(msg.axis_v), xyz(msg.normal))


def polygons_to_msg(polygons: list) -> pm.PlanarPolygons:
    """perch_interfaces/PlanarPolygons (flat points, ring starts, ring owners) of polygons with holes."""
    rings = [np.asarray(ring, np.float64).reshape(-1, 2) for poly in polygons for ring in poly]
    owner = [i for i, poly in enumerate(polygons) for _ in poly]
    sizes = np.array([len(r) for r in rings], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if len(rings) else np.zeros(0)
    msg = pm.PlanarPolygons()
    msg.points_xy = to_array(np.concatenate(rings) if rings else np.zeros((0, 2)), np.float32)
    msg.ring_starts = to_array(starts, np.uint32)
    msg.ring_polygon = to_array(np.asarray(owner), np.uint32)
    return msg


def polygons_from_msg(msg: pm.PlanarPolygons) -> list:
    """Polygons with holes of a perch_interfaces/PlanarPolygons."""
    points = from_array(msg.points_xy, np.float32, 2).astype(np.float64)
    starts = from_array(msg.ring_starts, np.uint32).astype(np.int64)
    owner = from_array(msg.ring_polygon, np.uint32).astype(np.int64)
    if len(starts) != len(owner):
        raise ValueError("polygons: ring_starts and ring_polygon differ in length")
    ends = np.append(starts[1:], len(points))
    polygons: list = [[] for _ in range(int(owner.max()) + 1 if len(owner) else 0)]
    for start, end, poly in zip(starts, ends, owner):
        polygons[poly].append(points[start:end])
    return polygons


def surface_to_msg(surface: Surface) -> pm.Surface:
    """perch_interfaces/Surface of a surface."""
    msg = pm.Surface(id=int(surface.id), surface_class=int(surface.surface_class),
                     frame=frame_to_msg(surface.frame), area=float(surface.area),
                     rms_distance=float(surface.rms_distance),
                     mean_color=np.asarray(surface.mean_color, np.float32),
                     boundary=polygons_to_msg(surface.boundary))
    msg.face_indices = to_array(surface.face_indices, np.uint32)
    return msg


def surface_from_msg(msg: pm.Surface) -> Surface:
    """Surface of a perch_interfaces/Surface."""
    return Surface(id=msg.id, frame=frame_from_msg(msg.frame), area=msg.area,
                   face_indices=from_array(msg.face_indices, np.uint32).astype(np.int64),
                   surface_class=SurfaceClass(msg.surface_class), rms_distance=msg.rms_distance,
                   mean_color=np.asarray(msg.mean_color, np.float64),
                   boundary=polygons_from_msg(msg.boundary))


def region_to_msg(region: PerchRegion) -> pm.PerchRegion:
    """perch_interfaces/PerchRegion of a perch region (with its mesh)."""
    return pm.PerchRegion(id=int(region.id), source_surface=int(region.source_surface),
                          surface_class=int(region.surface_class), area=float(region.area),
                          frame=frame_to_msg(region.frame), polygons=polygons_to_msg(region.polygons),
                          mesh=mesh_to_msg(region.mesh), evidence=evidence_to_msg(region.evidence))


def region_from_msg(msg: pm.PerchRegion) -> PerchRegion:
    """Perch region of a perch_interfaces/PerchRegion."""
    return PerchRegion(id=msg.id, source_surface=msg.source_surface,
                       surface_class=SurfaceClass(msg.surface_class), frame=frame_from_msg(msg.frame),
                       polygons=polygons_from_msg(msg.polygons), mesh=mesh_from_msg(msg.mesh, "region mesh"),
                       area=msg.area, evidence=evidence_from_msg(msg.evidence))


def evidence_to_msg(evidence: PerchEvidence) -> pm.PerchEvidence:
    """Safety evidence as its message (NOT_MEASURED, -1, where not measured)."""
    return pm.PerchEvidence(**{k: float(v) for k, v in vars(evidence).items()})


def evidence_from_msg(msg: pm.PerchEvidence) -> PerchEvidence:
    """Safety evidence from its message."""
    return PerchEvidence(**{k: float(getattr(msg, k)) for k in PerchEvidence.__dataclass_fields__})


def removal_to_msg(r: FilterRemoval) -> pm.FilterRemoval:
    """perch_interfaces/FilterRemoval of a surface's per-filter removed areas."""
    return pm.FilterRemoval(**{k: (int(v) if k == "surface_id" else float(v)) for k, v in vars(r).items()})


def removal_from_msg(msg: pm.FilterRemoval) -> FilterRemoval:
    """Per-filter removed areas of a perch_interfaces/FilterRemoval."""
    return FilterRemoval(**{k: getattr(msg, k) for k in FilterRemoval.__dataclass_fields__})


# --- target, placements ------------------------------------------------------------------------

def _box_msg(target: TargetVolume) -> pm.OrientedBox:
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = target.rotation, target.center
    return pm.OrientedBox(pose=pose_msg(pose), size=vector_msg(target.size))


def target_to_msg(target: TargetVolume) -> pm.TargetVolume:
    """The target as its message; a union of boxes is `box` plus `more_boxes`."""
    msg = pm.TargetVolume()
    if target.parts:
        if not all(v.is_box for v in target.volumes()):
            raise ValueError("a target of several volumes travels as boxes only; give every volume as a box")
        first, *rest = target.volumes()
        return pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX, box=_box_msg(first), more_boxes=[_box_msg(v) for v in rest])
    if target.is_box:
        msg.kind = pm.TargetVolume.KIND_BOX
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = target.rotation, target.center
        msg.box = pm.OrientedBox(pose=pose_msg(pose), size=vector_msg(target.size))
    else:
        msg.kind = pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT
        import mapbox_earcut

        k = len(target.footprint)
        # The footprint triangulated flat at the base height (ear clipping: concave outlines stay exact).
        vertices = np.column_stack([target.footprint, np.full(k, target.base)])
        triangles = mapbox_earcut.triangulate_float64(np.ascontiguousarray(target.footprint, np.float64),
                                                      np.array([k], np.uint32)).reshape(-1, 3)
        msg.footprint = mesh_to_msg(Mesh(vertices, triangles))
        msg.height = float(target.height)
    return msg


def box_from_msg(msg: pm.OrientedBox) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(center, size, rotation) of an OrientedBox."""
    pose = pose_matrix(msg.pose)
    return pose[:3, 3], xyz(msg.size), pose[:3, :3]


def target_from_msg(msg: pm.TargetVolume) -> TargetVolume | None:
    """The target volume, or None for KIND_DEFAULT (the serving node decides)."""
    if msg.kind == pm.TargetVolume.KIND_DEFAULT:
        return None
    if msg.kind == pm.TargetVolume.KIND_BOX:
        boxes = [box_from_msg(b) for b in [msg.box, *msg.more_boxes]]
        return TargetVolume.union([TargetVolume(center=c, size=s, rotation=r) for c, s, r in boxes])
    if msg.kind == pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT:
        return TargetVolume.from_footprint_mesh(mesh_from_msg(msg.footprint, "target footprint"), msg.height)
    raise ValueError(f"target volume: unknown kind {msg.kind}")


def placement_to_msg(p: CameraPlacement) -> pm.CameraPlacement:
    """perch_interfaces/CameraPlacement of a placement."""
    return pm.CameraPlacement(
        drone_index=int(p.drone_index), region_id=int(p.region_id), drone_pose=pose_msg(p.drone_pose),
        camera_pose=pose_msg(p.camera_pose), pan=float(p.pan), tilt=float(p.tilt), zoom=float(p.zoom),
        marginal_gain=float(p.marginal_gain), fitness=float(p.fitness), coverage=float(p.coverage),
        mean_uncertainty=float(p.mean_uncertainty), contribution=float(p.contribution),
        expected_contribution=float(p.expected_contribution), p5_contribution=float(p.p5_contribution),
        coverage_without=float(p.coverage_without), kview_coverage_without=float(p.kview_coverage_without))


def placement_from_msg(msg: pm.CameraPlacement) -> CameraPlacement:
    """Placement of a perch_interfaces/CameraPlacement."""
    return CameraPlacement(
        drone_index=msg.drone_index, region_id=msg.region_id, drone_pose=pose_matrix(msg.drone_pose),
        camera_pose=pose_matrix(msg.camera_pose), pan=msg.pan, tilt=msg.tilt, zoom=msg.zoom,
        marginal_gain=msg.marginal_gain, fitness=msg.fitness, coverage=msg.coverage,
        mean_uncertainty=msg.mean_uncertainty, contribution=msg.contribution,
        expected_contribution=msg.expected_contribution, p5_contribution=msg.p5_contribution,
        coverage_without=msg.coverage_without, kview_coverage_without=msg.kview_coverage_without)


def exclusion_to_msg(zone: ExclusionZone) -> pm.ExclusionZone:
    """perch_interfaces/ExclusionZone of an exclusion zone."""
    return pm.ExclusionZone(center=point_msg(zone.center), radius=float(zone.radius))


def exclusion_from_msg(msg: pm.ExclusionZone) -> ExclusionZone:
    """Exclusion zone of a perch_interfaces/ExclusionZone."""
    return ExclusionZone(xyz(msg.center), msg.radius)
