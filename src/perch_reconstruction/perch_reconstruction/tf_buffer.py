"""Camera poses from /tf and /tf_static: a small transform buffer keyed by frame pair (no tf2 wheels).

A robot publishes where it is as a tree of frames: `map -> odom -> base_link` moving (/tf) and
`base_link -> camera_link -> camera_optical_frame` fixed (/tf_static). `TransformBuffer.lookup`
composes the chain from the camera frame up to the world frame at an image's stamp: static edges
as they are, moving edges interpolated between the two samples around the stamp (translation
linearly, rotation by slerp, as tf2 does), or the nearest sample within `tolerance_ns` at the ends.
Pure numpy/scipy; no rclpy.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from perch_common.timing import time_ns
from perch_common.transforms import matrix_from_quaternion

# camera_link (x forward, y left, z up; REP 103) -> camera_optical_frame (z forward, x right, y down; REP 105)
OPTICAL_FROM_LINK = np.array([[0.0, 0.0, 1.0, 0.0],
                              [-1.0, 0.0, 0.0, 0.0],
                              [0.0, -1.0, 0.0, 0.0],
                              [0.0, 0.0, 0.0, 1.0]])


def transform_matrix(transform) -> np.ndarray:
    """4x4 of anything shaped like geometry_msgs/Transform (translation.x.., rotation.x..w)."""
    t, r = transform.translation, transform.rotation
    out = np.eye(4)
    out[:3, :3] = matrix_from_quaternion(np.array([r.x, r.y, r.z, r.w], np.float64))
    out[:3, 3] = [t.x, t.y, t.z]
    return out


@dataclass
class _Edge:
    """parent <- child samples: stamps (ns, sorted) and 4x4 parent-from-child matrices."""

    static: bool
    stamps: list[int] = field(default_factory=list)
    matrices: list[np.ndarray] = field(default_factory=list)


class TransformBuffer:
    """Transforms by child frame (each frame has one parent, as in tf); bounded per moving edge."""

    def __init__(self, capacity: int = 100_000):
        self.capacity = int(capacity)
        self._edges: dict[str, tuple[str, _Edge]] = {}   # child -> (parent, samples)

    def add(self, parent: str, child: str, stamp_ns: int, matrix: np.ndarray, static: bool = False) -> None:
        """One parent-from-child transform (a static one replaces the edge's earlier value)."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        known = self._edges.get(child)
        if known is None or known[0] != parent or known[1].static != static or static:
            known = (parent, _Edge(static))
            self._edges[child] = known
        edge = known[1]
        i = bisect.bisect(edge.stamps, stamp_ns)
        edge.stamps.insert(i, int(stamp_ns))
        edge.matrices.insert(i, np.asarray(matrix, np.float64))
        if len(edge.stamps) > self.capacity:
            del edge.stamps[0], edge.matrices[0]

    def add_message(self, msg, static: bool = False) -> int:
        """Every transform of a tf2_msgs/TFMessage (rclpy or decoded from a bag); returns how many."""
        for t in msg.transforms:
            self.add(t.header.frame_id, t.child_frame_id, time_ns(t.header.stamp), transform_matrix(t.transform),
                     static)
        return len(msg.transforms)

    def frames(self) -> set[str]:
        """Every frame named so far."""
        return set(self._edges) | {parent for parent, _ in self._edges.values()}

    def chain(self, target: str, source: str) -> list[str] | None:
        """Frames from `source` up to `target` (both included), None when target is not above source."""
        target, source = target.lstrip("/"), source.lstrip("/")
        path = [source]
        while path[-1] != target:
            if path[-1] not in self._edges or len(path) > len(self._edges) + 1:
                return None
            path.append(self._edges[path[-1]][0])
        return path

    def lookup(self, target: str, source: str, stamp_ns: int, tolerance_ns: int) -> np.ndarray | None:
        """target-from-source (e.g. map-from-camera) at `stamp_ns`; None when a moving edge has no
        sample around the stamp (within `tolerance_ns` beyond its first or last) or no chain links them."""
        path = self.chain(target, source)
        if path is None:
            return None
        out = np.eye(4)
        for child in path[:-1]:
            step = _at(self._edges[child][1], int(stamp_ns), int(tolerance_ns))
            if step is None:
                return None
            out = step @ out
        return out

    def why_not(self, target: str, source: str) -> str:
        """Why `lookup(target, source, ...)` cannot work at all ('' when a chain exists)."""
        if self.chain(target, source) is not None:
            return ""
        known = ", ".join(sorted(self.frames())) or "none"
        return f"no transform chain from '{source}' up to '{target}' in /tf and /tf_static (frames: {known})"


def _at(edge: _Edge, stamp: int, tolerance: int) -> np.ndarray | None:
    if edge.static:
        return edge.matrices[-1]
    stamps = edge.stamps
    i = bisect.bisect_left(stamps, stamp)
    if i < len(stamps) and stamps[i] == stamp:
        return edge.matrices[i]
    if 0 < i < len(stamps):
        t0, t1 = stamps[i - 1], stamps[i]
        a, b = edge.matrices[i - 1], edge.matrices[i]
        w = (stamp - t0) / (t1 - t0)
        out = np.eye(4)
        out[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))([w]).as_matrix()[0]
        out[:3, 3] = (1.0 - w) * a[:3, 3] + w * b[:3, 3]
        return out
    nearest = 0 if i == 0 else len(stamps) - 1
    return edge.matrices[nearest] if stamps and abs(stamps[nearest] - stamp) <= tolerance else None
