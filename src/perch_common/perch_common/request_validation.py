"""Validation of every stage request at the service boundary, one layer for all stage nodes.

`validate_request(request)` walks a perch_interfaces request (any ROS message, duck-typed through
`get_fields_and_field_types`, so this module never imports rclpy) and raises RequestError naming
the field and its bad value: non-finite numbers, non-unit quaternions, non-positive sizes and radii,
coordinates beyond 10 km, meshes whose size suggests millimetres or centimetres, targets far larger
than the mesh, vertex indices out of range, and camera or drone specs that are zero. What only one
stage understands (a PerchSpec, surface face indices) that stage checks itself.
Big arrays (mesh vertices, polygon points) are checked with numpy, never element by element.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from perch_common.mesh import MAX_COORDINATE, column_bounds, far_problem, scale_problem

MAX_TARGET_TO_MESH = 10.0        # a target this many times larger than the mesh is a unit or typing error
QUATERNION_TOLERANCE = 1e-3      # |norm - 1| accepted (float rounding of a unit quaternion)
MIN_TARGET_FACES = 100           # decimating a room below this leaves no planes to perch on
MAX_CAMERAS = 64
HINT_SCALE = "coordinates are metres (a mesh in millimetres needs --scale 0.001)"


class RequestError(ValueError):
    """A request field with a bad value; the message names the field, the value and the fix."""


@dataclass(frozen=True)
class _Field:
    path: str
    type_name: str


def _fields(msg) -> list[tuple[str, str]]:
    return list(type(msg).get_fields_and_field_types().items())


def _is_message(value) -> bool:
    return hasattr(type(value), "get_fields_and_field_types")


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _float_array(values) -> np.ndarray:
    if isinstance(values, np.ndarray):
        return values.astype(np.float64, copy=False).ravel()
    try:
        return np.frombuffer(values, dtype=np.float32 if getattr(values, "typecode", "d") == "f" else np.float64)
    except TypeError:
        return np.asarray(list(values), np.float64)


def _check_numbers(path: str, values: np.ndarray, limit: float | None) -> None:
    if values.size == 0:
        return
    finite = np.isfinite(values)
    if not finite.all():
        index = int(np.flatnonzero(~finite)[0])
        where = f"{path}[{index}]" if values.size > 1 else path
        raise RequestError(f"{where} = {values[index]}: must be a finite number "
                           f"({int((~finite).sum())} non-finite value(s) in {path})")
    if limit is not None:
        big = np.abs(values) > limit
        if big.any():
            index = int(np.flatnonzero(big)[0])
            where = f"{path}[{index}]" if values.size > 1 else path
            raise RequestError(f"{where} = {values[index]:.6g}: beyond {limit / 1000:g} km; {HINT_SCALE}")


def _check_mesh(path: str, mesh) -> np.ndarray:
    """Array sizes, finite vertices within range, triangle indices in range; returns the (V,3) vertices."""
    n_v, n_t = len(mesh.vertices), len(mesh.triangles)
    if n_v % 3 or n_t % 3:
        raise RequestError(f"{path}: vertices ({n_v}) and triangles ({n_t}) must be multiples of 3")
    vertices = _float_array(mesh.vertices)
    finite = np.isfinite(vertices)
    if not finite.all():
        bad = np.flatnonzero(~finite.reshape(-1, 3).all(axis=1))
        first = vertices.reshape(-1, 3)[bad[0]]
        raise RequestError(f"{path}.vertices: {len(bad)} vertices are NaN or infinite (first: vertex {int(bad[0])} = "
                           f"{first.tolist()})")
    if len(vertices):
        far = far_problem(*column_bounds(vertices.reshape(-1, 3)), path)
        if far:
            raise RequestError(far)
    _check_numbers(f"{path}.vertices", vertices, MAX_COORDINATE)
    if n_t:
        triangles = np.frombuffer(mesh.triangles, dtype=np.uint32) if not isinstance(mesh.triangles, np.ndarray) \
            else mesh.triangles.ravel()
        count = n_v // 3
        if triangles.max() >= count:  # per-face detail only when something is wrong
            bad_faces = np.flatnonzero((triangles.reshape(-1, 3) >= count).any(axis=1))
            face = int(bad_faces[0])
            raise RequestError(f"{path}.triangles: {len(bad_faces)} faces index vertices outside 0..{count - 1} "
                               f"(first: face {face} = {triangles.reshape(-1, 3)[face].tolist()})")
    return vertices.reshape(-1, 3)


def _check_quaternion(path: str, q) -> None:
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise RequestError(f"{path} = ({q.x:g}, {q.y:g}, {q.z:g}, {q.w:g}): not a unit quaternion (norm {norm:.4g}); "
                           "use x=y=z=0, w=1 for no rotation")


def _positive(path: str, value: float, what: str = "must be > 0") -> None:
    if not value > 0:
        raise RequestError(f"{path} = {value:g}: {what}")


def _non_negative(path: str, value: float) -> None:
    if value < 0:
        raise RequestError(f"{path} = {value:g}: must be >= 0")


def _check_box(path: str, box) -> None:
    for axis in ("x", "y", "z"):
        _positive(f"{path}.size.{axis}", getattr(box.size, axis), "box edge lengths must be > 0")


def _check_target(path: str, target) -> None:
    # TargetVolume kinds: 0 default, 1 box, 2 extruded footprint (perch_interfaces/msg/TargetVolume).
    if target.kind == 1:
        _check_box(f"{path}.box", target.box)
    elif target.kind == 2:
        if len(target.footprint.triangles) == 0:
            raise RequestError(f"{path}.footprint: an extruded-footprint target needs a footprint mesh with faces")
        _positive(f"{path}.height", target.height, "the extrusion height must be > 0")
    elif target.kind != 0:
        raise RequestError(f"{path}.kind = {target.kind}: unknown (0 default, 1 box, 2 extruded footprint)")


def _check_camera(path: str, camera) -> None:
    if not camera.specified:
        return
    for name in ("width", "height", "fx", "fy", "max_range", "baseline", "subpixel_error"):
        _positive(f"{path}.{name}", getattr(camera, name),
                  "a specified camera needs it > 0 (or set specified=false for the node's camera)")
    for name in ("cx", "cy", "min_range", "min_feature_size", "min_feature_pixels"):
        _non_negative(f"{path}.{name}", getattr(camera, name))
    if camera.min_range >= camera.max_range:
        raise RequestError(f"{path}.min_range = {camera.min_range:g}: must be below max_range ({camera.max_range:g})")


def _check_drone(path: str, drone) -> None:
    if not drone.specified:
        return
    _positive(f"{path}.radius", drone.radius, "a specified drone needs a radius > 0 (or specified=false)")
    _positive(f"{path}.pan_range", drone.pan_range, "a specified drone needs a pan range > 0")
    for name in ("camera_offset", "tilt_range", "target_deviation", "min_spacing"):
        _non_negative(f"{path}.{name}", getattr(drone, name))


# Checks run on a message of this type after its fields passed the generic checks.
_TYPE_CHECKS = {
    "geometry_msgs/Quaternion": _check_quaternion,
    "perch_interfaces/OrientedBox": _check_box,
    "perch_interfaces/TargetVolume": _check_target,
    "perch_interfaces/CameraSpec": _check_camera,
    "perch_interfaces/DroneSpec": _check_drone,
    "perch_interfaces/ExclusionZone": lambda path, zone: _positive(f"{path}.radius", zone.radius),
}
# Fields not in metres: excluded from the 10 km limit (still finite).
_UNLIMITED = {"perch_interfaces/CameraSpec"}
_FLOAT_TYPES = {"float", "double"}
# Integer fields as rosidl declares them: a Python int beyond the range is wrapped on the wire
# (4294967296 cameras arrive as 0), so it is refused here, where the message is still Python.
_INT_RANGES = {f"{sign}int{bits}": ((0, 2 ** bits - 1) if sign else (-2 ** (bits - 1), 2 ** (bits - 1) - 1))
               for sign in ("", "u") for bits in (8, 16, 32, 64)}
_TARGET_FIELDS = {1: ("kind", "box", "more_boxes"), 2: ("kind", "footprint", "height")}


def _walk(path: str, msg, type_name: str, limit: float | None) -> None:
    if type_name == "perch_interfaces/TriangleMesh":
        _check_mesh(path or "mesh", msg)
        return
    inner_limit = None if type_name in _UNLIMITED else limit
    for name, field_type in _fields(msg):
        if type_name == "perch_interfaces/TargetVolume" and name not in _TARGET_FIELDS.get(msg.kind, ("kind",)):
            continue  # the fields of the other kinds are unused (and may be left zero)
        value = getattr(msg, name)
        field_path = _join(path, name)
        base = field_type.split("<", 1)[-1].rstrip(">").split("[", 1)[0]
        if base in _INT_RANGES and field_type == base:
            low, high = _INT_RANGES[base]
            if not low <= value <= high:
                raise RequestError(f"{field_path} = {value}: out of range for {base} ({low}..{high})")
        elif base in _FLOAT_TYPES:
            if field_type in _FLOAT_TYPES:
                _check_numbers(field_path, np.array([value], np.float64), inner_limit)
            else:
                _check_numbers(field_path, _float_array(value), inner_limit)
        elif "/" in base:
            items = value if field_type != base else [value]
            for index, item in enumerate(items):
                item_path = f"{field_path}[{index}]" if field_type != base else field_path
                _walk(item_path, item, base, inner_limit)
    check = _TYPE_CHECKS.get(type_name)
    if check is not None:
        check(path, msg)


def _mesh_extent(vertices: np.ndarray) -> float:
    if len(vertices) == 0:
        return 0.0
    low, high = column_bounds(vertices)
    return float(np.max(high - low))


def _held_extent(content_id: str) -> float:
    """Size of the mesh this process holds under `content_id` (0 when it holds none: its stage says so)."""
    from perch_common.mesh_cache import PROCESS_CACHE

    held = PROCESS_CACHE.get(content_id)
    if held is None or held.num_vertices == 0:
        return 0.0
    return held.derived("extent", lambda: _mesh_extent(held.vertices))


def _target_extent(target) -> float:
    if target.kind == 1:
        boxes = [target.box, *getattr(target, "more_boxes", [])]
        return max(max(b.size.x, b.size.y, b.size.z) for b in boxes)
    if target.kind == 2:
        footprint = _float_array(target.footprint.vertices).reshape(-1, 3)
        return max(_mesh_extent(footprint), float(target.height))
    return 0.0


def validate_request(request, mesh_field: str = "mesh") -> None:
    """Raise RequestError for the first bad field of a stage request; returns None when it is sane."""
    if not _is_message(request):
        return  # not a ROS message (a test double): nothing to walk
    _walk("", request, "", MAX_COORDINATE)
    fields = dict(_fields(request))
    mesh = getattr(request, mesh_field, None) if mesh_field in fields else None
    extent = 0.0
    if mesh is not None and len(mesh.vertices):
        vertices = _float_array(mesh.vertices).reshape(-1, 3)
        extent = _mesh_extent(vertices)
        units = scale_problem(extent, mesh_field)
        if units:
            raise RequestError(units)
    elif mesh is not None and getattr(mesh, "content_id", ""):
        extent = _held_extent(mesh.content_id)   # a mesh named by id: the target is checked against it too
    target = getattr(request, "target", None) if "target" in fields else None
    if target is not None and extent > 0:
        size = _target_extent(target)
        if size > MAX_TARGET_TO_MESH * extent:
            raise RequestError(f"target is {size:.4g} m across but the {mesh_field} only {extent:.4g} m: more than "
                               f"{MAX_TARGET_TO_MESH:g}x larger; check the target's units and size")
    if "target_faces" in fields and 0 < request.target_faces < MIN_TARGET_FACES:
        raise RequestError(f"target_faces = {request.target_faces}: give 0 (no decimation / the node's default) "
                           f"or at least {MIN_TARGET_FACES}")
    if "num_cameras" in fields and request.num_cameras > MAX_CAMERAS:
        raise RequestError(f"num_cameras = {request.num_cameras}: at most {MAX_CAMERAS} (0: the node's default)")
