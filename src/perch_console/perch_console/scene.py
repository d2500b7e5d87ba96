"""ROS markers into viser scene nodes: what RViz and Foxglove draw, drawn in the browser.

The console renders the graph's own /perch/scan_marker and /perch/markers (no second picture of the
mission). Markers of one namespace and type are merged into one scene node (one line set, one
vertex-coloured mesh): a few dozen nodes instead of hundreds keep the browser light.
"""

from __future__ import annotations

import numpy as np
from visualization_msgs.msg import Marker

from perch_common.transforms import pose_to_matrix


def _xyz(points) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in points], np.float64).reshape(-1, 3)


def _rgb(marker: Marker, count: int) -> np.ndarray:
    """(count,3) uint8 colours of a marker's points: per-point colours when given, else its colour."""
    if len(marker.colors) == count:
        return np.clip(np.array([(c.r, c.g, c.b) for c in marker.colors]) * 255, 0, 255).astype(np.uint8)
    c = marker.color
    return np.tile(np.clip(np.array([c.r, c.g, c.b]) * 255, 0, 255).astype(np.uint8), (count, 1))


def _posed(marker: Marker, xyz: np.ndarray) -> np.ndarray:
    m = pose_to_matrix(marker.pose)
    return xyz @ m[:3, :3].T + m[:3, 3]


def wxyz_of(pose) -> tuple[float, float, float, float]:
    """viser's (w, x, y, z) of a geometry_msgs Pose's orientation."""
    q = pose.orientation
    return (q.w, q.x, q.y, q.z) if (q.w, q.x, q.y, q.z) != (0.0, 0.0, 0.0, 0.0) else (1.0, 0.0, 0.0, 0.0)


def triangle_mesh(marker: Marker):
    """A TRIANGLE_LIST marker as a trimesh with per-vertex colours (its pose applied)."""
    import trimesh

    xyz = _posed(marker, _xyz(marker.points))
    count = len(xyz) - len(xyz) % 3
    rgb = _rgb(marker, len(xyz))[:count]
    alpha = np.full((count, 1), int(np.clip(marker.color.a, 0, 1) * 255) if not marker.colors else 255, np.uint8)
    return trimesh.Trimesh(xyz[:count], np.arange(count).reshape(-1, 3), vertex_colors=np.hstack([rgb, alpha]),
                           process=False)


def merged_groups(markers: list[Marker]) -> dict[tuple[str, int], dict]:
    """Markers by (namespace, type): LINE_LIST and TRIANGLE_LIST merged (points, colours), the rest listed."""
    groups: dict[tuple[str, int], dict] = {}
    for marker in markers:
        if marker.action != Marker.ADD:
            continue
        group = groups.setdefault((marker.ns, marker.type), {"points": [], "colors": [], "markers": []})
        if marker.type in (Marker.LINE_LIST, Marker.TRIANGLE_LIST) and marker.points:
            xyz = _posed(marker, _xyz(marker.points))
            keep = len(xyz) - len(xyz) % (2 if marker.type == Marker.LINE_LIST else 3)
            group["points"].append(xyz[:keep])
            group["colors"].append(_rgb(marker, len(xyz))[:keep])
        group["markers"].append(marker)
    return groups


def draw_markers(scene, prefix: str, markers: list[Marker]) -> list:
    """Add the markers under `prefix` to a viser scene; returns the handles (to remove them later)."""
    import trimesh

    handles = []
    for (ns, kind), group in merged_groups(markers).items():
        name = f"{prefix}/{ns}_{kind}"
        if kind == Marker.LINE_LIST and group["points"]:
            points = np.vstack(group["points"]).reshape(-1, 2, 3)
            colors = np.vstack(group["colors"]).reshape(-1, 2, 3)
            width = max(float(group["markers"][0].scale.x), 0.005)
            handles.append(scene.add_line_segments(name, points, colors, thickness=width))
        elif kind == Marker.TRIANGLE_LIST and group["points"]:
            xyz, rgb = np.vstack(group["points"]), np.vstack(group["colors"])
            first = group["markers"][0]
            opacity = None if first.colors or first.color.a >= 0.99 else float(first.color.a)
            if opacity is None:
                mesh = trimesh.Trimesh(xyz, np.arange(len(xyz)).reshape(-1, 3), vertex_colors=rgb, process=False)
                handles.append(scene.add_mesh_trimesh(name, mesh))
            else:   # translucent: one colour per namespace (viser's simple mesh), as RViz blends it
                handles.append(scene.add_mesh_simple(name, xyz, np.arange(len(xyz)).reshape(-1, 3),
                                                     color=tuple(int(v) for v in rgb[0]), opacity=opacity,
                                                     side="double"))
        else:
            for marker in group["markers"]:
                handles += _single(scene, f"{name}_{marker.id}", marker)
    return handles


def _single(scene, name: str, marker: Marker) -> list:
    position = (marker.pose.position.x, marker.pose.position.y, marker.pose.position.z)
    rgb = tuple(int(v) for v in _rgb(marker, 1)[0])
    if marker.type == Marker.CUBE:
        return [scene.add_box(name, color=rgb, dimensions=(marker.scale.x, marker.scale.y, marker.scale.z),
                              opacity=float(marker.color.a), position=position, wxyz=wxyz_of(marker.pose),
                              cast_shadow=False, receive_shadow=False)]
    if marker.type == Marker.SPHERE:
        return [scene.add_icosphere(name, radius=max(marker.scale.x, 1e-3) / 2, color=rgb, position=position,
                                    subdivisions=2)]
    if marker.type == Marker.TEXT_VIEW_FACING and marker.text:
        return [scene.add_label(name, marker.text, position=position, font_screen_scale=0.8)]
    return []
