"""The mission as RViz/Foxglove markers (visualization_msgs/MarkerArray), all in the input's own frame.

Surfaces outlined in their class colour, the area each safety filter removed (a label per surface,
coloured by the filter that removed most), perch regions coloured by surface class, the target
volume, and for each proposal its perch (coloured
by status), the camera frustum drawn from the CameraSpec, and a short label `#id`. Every array
starts with DELETEALL, so the latched last message is the whole current picture. The scan itself goes
out as one decimated TRIANGLE_LIST with per-vertex colours (`scan_marker`, within a triangle budget
so a viewer stays light). Labels stay short: the removal numbers belong in the report and the console.
Built from messages and numpy only (no rclpy).
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from perch_common.conventions import FILTER_COLOURS, FILTER_NAMES
from perch_common.transforms import pose_to_matrix, quaternion_from_matrix
from perch_interfaces import msg as pm

STATUS_NAMES = {pm.Proposal.STATUS_PENDING: "pending", pm.Proposal.STATUS_ACCEPTED: "accepted",
                pm.Proposal.STATUS_REJECTED: "rejected", pm.Proposal.STATUS_FAILED: "failed"}
STATUS_COLOURS = {pm.Proposal.STATUS_PENDING: (1.0, 0.75, 0.1), pm.Proposal.STATUS_ACCEPTED: (0.1, 0.8, 0.25),
                  pm.Proposal.STATUS_REJECTED: (0.9, 0.2, 0.2), pm.Proposal.STATUS_FAILED: (0.55, 0.2, 0.7)}
CLASS_COLOURS = {pm.Surface.CLASS_UNKNOWN: (0.6, 0.6, 0.6), pm.Surface.CLASS_FLOOR: (0.55, 0.4, 0.25),
                 pm.Surface.CLASS_WALL: (0.25, 0.5, 0.9), pm.Surface.CLASS_CEILING: (0.9, 0.9, 0.55),
                 pm.Surface.CLASS_INTERMEDIATE: (0.6, 0.3, 0.8)}
SCAN_TRIANGLE_BUDGET = 60_000  # triangles of the viewers' scan marker: ~4 MB on the wire, smooth in RViz/Foxglove
SCAN_GREY = (0.72, 0.72, 0.72)  # a scan without colours
FRUSTUM_DRAW_RANGE = 1.5  # m: frustums are drawn this deep (or to max_range if shorter), not to the full range


def camera_frame(slot: int) -> str:
    """The tf frame of drone `slot`'s camera (optical convention), on tf_static once accepted."""
    return f"perch_drone_{slot}_camera_optical"


def _colour(rgb, alpha: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(alpha))


def _points(xyz: np.ndarray) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in np.asarray(xyz, np.float64).reshape(-1, 3)]


def _homogeneous(matrix: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    given = np.asarray(matrix, np.float64)
    out[:given.shape[0], :given.shape[1]] = given
    return out


def _apply(matrix: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    m = _homogeneous(matrix)
    return np.asarray(xyz, np.float64).reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


def _marker(kind: int, ns: str, marker_id: int, frame_id: str, stamp, rgb, alpha: float = 1.0) -> Marker:
    marker = Marker(type=kind, ns=ns, id=marker_id, action=Marker.ADD, color=_colour(rgb, alpha))
    marker.header.frame_id, marker.header.stamp = frame_id, stamp
    marker.pose.orientation.w = 1.0
    marker.scale = Vector3(x=1.0, y=1.0, z=1.0)
    return marker


def frustum_corners(camera: pm.CameraSpec, depth: float) -> np.ndarray:
    """(4,3) far corners of the camera's view at `depth` in its optical frame (z forward, x right, y down)."""
    if camera.fx <= 0 or camera.fy <= 0 or camera.width == 0 or camera.height == 0:
        raise ValueError("camera spec without intrinsics (width, height, fx, fy): cannot draw its frustum")
    u = np.array([0.0, camera.width, camera.width, 0.0])
    v = np.array([0.0, 0.0, camera.height, camera.height])
    return np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth,
                     np.full(4, depth)], axis=1)


def frustum_lines(camera_pose: Pose, camera: pm.CameraSpec, zoom: float = 1.0) -> np.ndarray:
    """(16,3) LINE_LIST end points: apex to the four far corners, and the far rectangle."""
    depth = min(FRUSTUM_DRAW_RANGE, camera.max_range) if camera.max_range > 0 else FRUSTUM_DRAW_RANGE
    corners = frustum_corners(camera, depth)
    corners[:, :2] /= max(zoom, 1.0)  # zooming in narrows the view
    world = _apply(pose_to_matrix(camera_pose), np.vstack([np.zeros(3), corners]))
    apex, far = world[0], world[1:]
    segments = [(apex, c) for c in far] + [(far[i], far[(i + 1) % 4]) for i in range(4)]
    return np.array(segments).reshape(-1, 3)


def proposal_markers(proposal: pm.Proposal, camera: pm.CameraSpec, frame_id: str, stamp) -> list[Marker]:
    """The perch (sphere), its camera frustum and its label `#id status gain`, in the input frame."""
    placement, rgb = proposal.placement, STATUS_COLOURS.get(proposal.status, (0.5, 0.5, 0.5))
    perch = _marker(Marker.SPHERE, "perch_proposals", proposal.id, frame_id, stamp, rgb)
    perch.pose = Pose(position=placement.drone_pose.position, orientation=Quaternion(w=1.0))
    perch.scale = Vector3(x=0.15, y=0.15, z=0.15)
    frustum = _marker(Marker.LINE_LIST, "camera_frustums", proposal.id, frame_id, stamp, rgb)
    frustum.scale = Vector3(x=0.01, y=0.0, z=0.0)
    frustum.points = _points(frustum_lines(placement.camera_pose, camera, placement.zoom))
    label = _marker(Marker.TEXT_VIEW_FACING, "proposal_labels", proposal.id, frame_id, stamp, (1.0, 1.0, 1.0))
    label.pose = Pose(position=Point(x=placement.drone_pose.position.x, y=placement.drone_pose.position.y,
                                     z=placement.drone_pose.position.z + 0.25), orientation=Quaternion(w=1.0))
    label.scale = Vector3(x=0.0, y=0.0, z=0.12)
    label.text = f"#{proposal.id}"  # status is the colour; drone, gain and evidence are in the console and report
    return [perch, frustum, label]


def region_marker(region: pm.PerchRegion, to_input: np.ndarray, frame_id: str, stamp) -> Marker | None:
    """A perch region's triangles (TRIANGLE_LIST), coloured by its surface's class."""
    vertices = np.asarray(region.mesh.vertices, np.float64).reshape(-1, 3)
    triangles = np.asarray(region.mesh.triangles, np.int64).reshape(-1)
    if not len(triangles):
        return None
    marker = _marker(Marker.TRIANGLE_LIST, "perch_regions", region.id, frame_id, stamp,
                     CLASS_COLOURS.get(region.surface_class, CLASS_COLOURS[pm.Surface.CLASS_UNKNOWN]), 0.7)
    marker.points = _points(_apply(to_input, vertices[triangles]))
    return marker


def target_marker(target: pm.TargetVolume, to_input: np.ndarray, frame_id: str, stamp) -> Marker | None:
    """The target volume: a translucent box, or the footprint's triangles at the bottom and the top."""
    rgb = (0.2, 0.9, 0.9)
    if target.kind == pm.TargetVolume.KIND_BOX:
        marker = _marker(Marker.CUBE, "target_volume", 0, frame_id, stamp, rgb, 0.25)
        m = _homogeneous(to_input) @ pose_to_matrix(target.box.pose)
        q = quaternion_from_matrix(m[:3, :3])
        marker.pose = Pose(position=Point(x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
                           orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        marker.scale = Vector3(x=float(target.box.size.x), y=float(target.box.size.y), z=float(target.box.size.z))
        return marker
    if target.kind == pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT:
        vertices = np.asarray(target.footprint.vertices, np.float64).reshape(-1, 3)
        triangles = np.asarray(target.footprint.triangles, np.int64).reshape(-1)
        if not len(triangles):
            return None
        bottom = vertices[triangles]
        top = bottom + np.array([0.0, 0.0, float(target.height)])  # the stages' frame is gravity-aligned
        marker = _marker(Marker.TRIANGLE_LIST, "target_volume", 0, frame_id, stamp, rgb, 0.25)
        marker.points = _points(_apply(to_input, np.vstack([bottom, top])))
        return marker
    return None


def surface_outline(surface: pm.Surface, to_input: np.ndarray, frame_id: str, stamp, rgb, ns: str,
                    width: float) -> Marker | None:
    """A surface's boundary rings (LINE_LIST in 3D from its plane frame), coloured `rgb`."""
    xy = np.asarray(surface.boundary.points_xy, np.float64).reshape(-1, 2)
    if not len(xy):
        return None
    f = surface.frame
    origin = np.array([f.origin.x, f.origin.y, f.origin.z])
    u, v = np.array([f.axis_u.x, f.axis_u.y, f.axis_u.z]), np.array([f.axis_v.x, f.axis_v.y, f.axis_v.z])
    points = _apply(to_input, origin + xy[:, :1] * u + xy[:, 1:] * v)
    starts = list(np.asarray(surface.boundary.ring_starts, np.int64)) + [len(points)]
    segments = []
    for a, b in zip(starts[:-1], starts[1:]):
        ring = np.arange(a, b)
        segments += [points[ring], points[np.roll(ring, -1)]]
    marker = _marker(Marker.LINE_LIST, ns, surface.id, frame_id, stamp, rgb)
    marker.scale = Vector3(x=width, y=0.0, z=0.0)
    pairs = np.stack([np.concatenate(segments[0::2]), np.concatenate(segments[1::2])], axis=1)
    marker.points = _points(pairs)
    return marker


def display_mesh(mesh, max_triangles: int = SCAN_TRIANGLE_BUDGET):
    """`mesh` (perch_common Mesh) decimated for display to at most `max_triangles`, colours kept.

    Vertex clustering on a grid (perch_reconstruction's, colours averaged per cell): linear time and
    shape-faithful enough to recognise a room; the grid is coarsened until the budget holds.
    """
    from perch_reconstruction.mesh_ops import cluster_vertices

    if max_triangles <= 0:
        raise ValueError(f"max_triangles must be positive, got {max_triangles}")
    target = max_triangles
    while mesh.num_faces > max_triangles:
        mesh = cluster_vertices(mesh, target)
        target = max(1, int(target * 0.7))
    return mesh


def scan_marker(mesh, to_input: np.ndarray, frame_id: str, stamp,
                max_triangles: int = SCAN_TRIANGLE_BUDGET) -> tuple[Marker, np.ndarray, np.ndarray | None] | None:
    """The scan as one TRIANGLE_LIST marker with per-vertex colours (grey without), decimated to at
    most `max_triangles`, in the input frame (`to_input` takes the mesh's frame there): the marker
    without its arrays, its corners (N,3) and their RGBA colours (N,4, None when grey), for
    perch_common.ros.marker_wire.serialized_marker (no Python object per corner)."""
    shown = display_mesh(mesh, max_triangles)
    if shown.num_faces == 0:
        return None
    marker = _marker(Marker.TRIANGLE_LIST, "scan", 0, frame_id, stamp, (1.0, 1.0, 1.0))
    corners = shown.faces.reshape(-1)
    points = _apply(to_input, shown.vertices[corners])
    colors = None
    if shown.vertex_colors is not None:
        colors = np.ones((len(corners), 4))
        colors[:, :3] = shown.vertex_colors[corners, :3].astype(np.float64) / 255.0
    else:
        marker.color = _colour(SCAN_GREY)
    return marker, points, colors


def removal_label(surface: pm.Surface, removal: pm.FilterRemoval, to_input: np.ndarray, frame_id: str, stamp,
                  filter_names, filter_colours) -> Marker | None:
    """A short label `S<id>` on a surface a filter trimmed, coloured by the filter that removed most
    (how much each removed is in the report and the console, not in a 3D label)."""
    removed = [(float(getattr(removal, name)), name, colour) for name, colour in zip(filter_names, filter_colours)
               if float(getattr(removal, name)) > 0]
    if not removed:
        return None
    worst = max(removed)
    f = surface.frame
    position = _apply(to_input, [f.origin.x, f.origin.y, f.origin.z])[0]
    marker = _marker(Marker.TEXT_VIEW_FACING, "area_removed", surface.id, frame_id, stamp,
                     np.asarray(worst[2], np.float64) / 255.0)
    marker.pose = Pose(position=Point(x=float(position[0]), y=float(position[1]), z=float(position[2])),
                       orientation=Quaternion(w=1.0))
    marker.scale = Vector3(x=0.0, y=0.0, z=0.1)
    marker.text = f"S{surface.id}"
    return marker


def scene_markers(regions: list[pm.PerchRegion], target: pm.TargetVolume, to_input: np.ndarray, frame_id: str,
                  stamp, surfaces: list[pm.Surface] = (), removals: list[pm.FilterRemoval] = ()) -> list[Marker]:
    """What stays the same through a mission: surfaces, removal labels, regions and the target (input frame).

    regions and target are in the stages' gravity-aligned frame; `to_input` takes them to the input frame.
    """
    markers = []
    for surface in surfaces:  # every segmented surface, outlined in its class colour
        rgb = CLASS_COLOURS.get(surface.surface_class, CLASS_COLOURS[pm.Surface.CLASS_UNKNOWN])
        markers.append(surface_outline(surface, to_input, frame_id, stamp, rgb, "surfaces", 0.02))
    by_id = {s.id: s for s in surfaces}
    for removal in removals:  # what the safety filters took away, labelled and coloured by filter
        if removal.surface_id in by_id:
            markers.append(removal_label(by_id[removal.surface_id], removal, to_input, frame_id, stamp,
                                         FILTER_NAMES, FILTER_COLOURS))
    markers += [m for m in (region_marker(r, to_input, frame_id, stamp) for r in regions) if m is not None]
    markers.append(target_marker(target, to_input, frame_id, stamp))
    return [m for m in markers if m is not None]


def mission_markers(proposals: list[pm.Proposal], regions: list[pm.PerchRegion], target: pm.TargetVolume,
                    camera: pm.CameraSpec, to_input: np.ndarray, frame_id: str, stamp,
                    surfaces: list[pm.Surface] = (), removals: list[pm.FilterRemoval] = ()) -> MarkerArray:
    """The whole current picture: DELETEALL, then surfaces, regions, target and every proposal (input frame).

    regions and target are in the stages' gravity-aligned frame (`to_input` takes them to the input
    frame); proposals are the published ones (already in the input frame).
    """
    return current_picture(proposals, camera, frame_id, stamp,
                           scene_markers(regions, target, to_input, frame_id, stamp, surfaces, removals))


def current_picture(proposals: list[pm.Proposal], camera: pm.CameraSpec, frame_id: str, stamp,
                    scene: list[Marker]) -> MarkerArray:
    """DELETEALL, the mission's `scene` (scene_markers, re-stamped: a node builds them once a mission,
    not for every proposal event) and every proposal."""
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id, clear.header.stamp = frame_id, stamp
    for marker in scene:
        marker.header.stamp = stamp
    markers = [clear, *scene]
    for proposal in proposals:
        markers += proposal_markers(proposal, camera, frame_id, stamp)
    return MarkerArray(markers=[m for m in markers if m is not None])
