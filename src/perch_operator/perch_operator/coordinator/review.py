"""Surface review before filtering: the operator approves, rejects or crops the largest surfaces.

Pure Python (no rclpy): the node opens a review, publishes it, and a /perch/review_surfaces call
decides it; the mission thread waits on the decision. A cropped surface keeps only the part of it
inside the operator's box (the thesis let its operator trim a surface whose segmentation ran over a
poster or a door): its faces with their centroid in the box, its outline cut to the box.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from perch_common.mesh import Mesh
from perch_common.polygons import faces_outline, from_shapely, to_shapely
from perch_common.types import PlaneFrame, Surface
from perch_operator.coordinator.crop import Box


class ReviewError(ValueError):
    """A decision that cannot be applied (unknown review, unknown surface, decided twice)."""


class ReviewDesk:
    """Open surface reviews and the operator's rejections, waited on by the mission."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._next_id = 1
        self._surfaces: dict[int, set[int]] = {}
        self._decisions: dict[int, set[int]] = {}
        self._crops: dict[int, dict[int, Box]] = {}
        self._outlines: dict[int, dict[int, tuple[PlaneFrame, list]]] = {}
        self._decided = threading.Condition(self._lock)

    def open(self, surface_ids: list[int], outlines: dict[int, tuple[PlaneFrame, list]] | None = None) -> int:
        """A new review of these surfaces; returns its id. `outlines` (surface id -> plane frame and
        outline, in the frame crop boxes come in) lets a crop box that misses its surface be refused."""
        with self._lock:
            review_id = self._next_id
            self._next_id += 1
            self._surfaces[review_id] = set(int(i) for i in surface_ids)
            self._outlines[review_id] = dict(outlines or {})
            return review_id

    def decide(self, review_id: int, rejected: list[int], crops: dict[int, Box] | None = None) -> set[int]:
        """Record the decision: every reviewed surface not in `rejected` is approved, those in `crops`
        (surface id -> the box to keep) trimmed to their box."""
        crops = {int(k): box for k, box in (crops or {}).items()}
        with self._lock:
            if review_id not in self._surfaces:
                raise ReviewError(f"no surface review {review_id} is open")
            if review_id in self._decisions:
                raise ReviewError(f"surface review {review_id} was already decided")
            unknown = sorted((set(int(i) for i in rejected) | set(crops)) - self._surfaces[review_id])
            if unknown:
                raise ReviewError(f"surface(s) {unknown} are not part of review {review_id} "
                                  f"(reviewed: {sorted(self._surfaces[review_id])})")
            both = sorted(set(int(i) for i in rejected) & set(crops))
            if both:
                raise ReviewError(f"surface(s) {both} are both rejected and cropped: reject a surface or crop it")
            for surface_id, box in crops.items():
                known = self._outlines[review_id].get(surface_id)
                if known is not None and not cropped_outline(known[0], known[1], box):
                    raise ReviewError(f"the crop box for surface {surface_id} (centre "
                                      f"{np.round(box.center, 2).tolist()} m, size {np.round(box.size, 2).tolist()} m) "
                                      "does not overlap it: draw the box over the part of the surface to keep")
            self._decisions[review_id] = set(int(i) for i in rejected)
            self._crops[review_id] = crops
            self._decided.notify_all()
            return self._decisions[review_id]

    def crops(self, review_id: int) -> dict[int, Box]:
        """The decided review's crop boxes (surface id -> box); empty when none or undecided."""
        with self._lock:
            return dict(self._crops.get(review_id, {}))

    def wait(self, review_id: int, timeout: float, cancelled: Callable[[], bool]) -> set[int]:
        """The rejected surface ids once decided; TimeoutError after `timeout` s (0: no limit)."""
        started = time.monotonic()
        with self._lock:
            while review_id not in self._decisions:
                if cancelled():
                    raise TimeoutError(f"mission cancelled during surface review {review_id}")
                if timeout > 0 and time.monotonic() - started > timeout:
                    raise TimeoutError(f"no decision on surface review {review_id} within {timeout:g} s "
                                       "(perch operator review ID [--reject ...]; parameter confirm_timeout)")
                self._decided.wait(0.25)
            return self._decisions[review_id]


# --- Cropping a reviewed surface to the part that is good -------------------------------------------------


@dataclass
class ReviewDecision:
    """An operator's decision on a review: the rejected surface ids, and the approved surfaces to
    trim, each to the part inside its box (input frame, as sent)."""

    rejected: set[int]
    crops: dict[int, Box] = field(default_factory=dict)


def box_section(frame: PlaneFrame, box: Box) -> np.ndarray:
    """(K,2) convex polygon: where the plane of `frame` passes through `box`, in plane coordinates
    (empty when the plane misses the box)."""
    offset = (frame.origin - box.center) @ box.rotation         # the plane's origin in box coordinates
    du, dv = frame.axis_u @ box.rotation, frame.axis_v @ box.rotation
    reach = float(np.linalg.norm(frame.origin - box.center) + np.linalg.norm(box.size))
    polygon = np.array([[-reach, -reach], [reach, -reach], [reach, reach], [-reach, reach]])
    # |offset_k + a du_k + b dv_k| <= size_k / 2 for each box axis k: six half-planes clip the square.
    for k in range(3):
        for sign in (1.0, -1.0):
            normal, limit = sign * np.array([du[k], dv[k]]), box.size[k] / 2 - sign * offset[k]
            polygon = _clip(polygon, normal, limit)
            if len(polygon) == 0:
                return polygon
    return polygon


def _clip(polygon: np.ndarray, normal: np.ndarray, limit: float) -> np.ndarray:
    """The part of a convex polygon where normal . p <= limit (Sutherland-Hodgman, one edge)."""
    side = polygon @ normal - limit
    kept = []
    for i in range(len(polygon)):
        j = (i + 1) % len(polygon)
        if side[i] <= 0:
            kept.append(polygon[i])
        if (side[i] < 0 < side[j]) or (side[j] < 0 < side[i]):
            t = side[i] / (side[i] - side[j])
            kept.append(polygon[i] + t * (polygon[j] - polygon[i]))
    return np.array(kept).reshape(-1, 2)


def cropped_outline(frame: PlaneFrame, boundary: list, box: Box) -> list:
    """A surface's outline (polygons of rings in plane coordinates) cut to the box; [] when they do
    not overlap."""
    import shapely

    section = box_section(frame, box)
    if len(section) < 3 or not boundary:
        return []
    kept = to_shapely(boundary).intersection(shapely.Polygon(section))
    return [p for p in from_shapely(kept) if len(p[0]) >= 3]


def crop_surface(surface: Surface, mesh: Mesh, box: Box) -> Surface:
    """The surface trimmed to the box: the faces whose centroid lies inside it, its outline cut to the
    box's section with its plane, its area the kept faces' area and its origin their area-weighted
    centroid (on the plane); plane axes, class, RMS and colour stay. ValueError when nothing is left.
    `mesh` is the mesh the surface was segmented from, in the surface's frame, as is the box."""
    faces = np.asarray(surface.face_indices, np.int64)
    triangles = mesh.vertices[mesh.faces[faces]]
    centroids = triangles.mean(axis=1)
    inside = box.contains(centroids)
    if not inside.any():
        raise ValueError(f"surface {surface.id}: none of its {len(faces)} faces lies inside the crop box "
                         f"(centre {np.round(box.center, 2).tolist()} m, size {np.round(box.size, 2).tolist()} m); "
                         "draw the box over the part of the surface to keep")
    kept = triangles[inside]
    areas = mesh.face_areas()[faces[inside]]
    frame = surface.frame
    weights = areas if areas.sum() > 0 else np.ones(len(areas))
    shift = frame.to_plane(np.average(kept.mean(axis=1), axis=0, weights=weights)[None])[0]
    new_frame = PlaneFrame(frame.to_world(shift[None])[0], frame.axis_u.copy(), frame.axis_v.copy(),
                           frame.normal.copy())
    outline = cropped_outline(frame, surface.boundary, box) if surface.boundary else []
    if surface.boundary and not outline:   # the faces' centroids are inside but the outline is not
        outline = faces_outline(frame, kept)
    boundary = [[np.asarray(ring, np.float64) - shift for ring in polygon] for polygon in outline]
    return replace(surface, frame=new_frame, area=float(areas.sum()), face_indices=faces[inside],
                   boundary=boundary, mean_color=np.array(surface.mean_color, np.float64))


def cropped_surfaces(surfaces: list, crops: dict[int, Box], mesh: Mesh, to_aligned: np.ndarray) -> list:
    """Surface messages (gravity-aligned, segmented from `mesh`) with those in `crops` trimmed to their
    box; the boxes come in the input's frame, `to_aligned` (4x4) turns them into the surfaces' frame."""
    from perch_common.ros.conversions import surface_from_msg, surface_to_msg

    rotation, shift = np.asarray(to_aligned)[:3, :3], np.asarray(to_aligned)[:3, 3]
    out = []
    for msg in surfaces:
        box = crops.get(int(msg.id))
        if box is not None:
            aligned = Box(rotation @ box.center + shift, box.size, rotation @ box.rotation)
            msg = surface_to_msg(crop_surface(surface_from_msg(msg), mesh, aligned))
        out.append(msg)
    return out


def review_outlines(surfaces: list) -> dict[int, tuple[PlaneFrame, list]]:
    """Surface id -> (plane frame, outline) of the surface messages under review (ReviewDesk.open)."""
    from perch_common.ros.conversions import frame_from_msg, polygons_from_msg

    return {int(s.id): (frame_from_msg(s.frame), polygons_from_msg(s.boundary)) for s in surfaces}


def review_crops(request) -> dict[int, Box]:
    """Surface id -> crop box of a ReviewSurfaces request; ValueError naming what is wrong."""
    from perch_operator.coordinator.messages import box_from_ros

    ids, boxes = list(request.cropped_surface_ids), list(request.crop_boxes)
    if len(ids) != len(boxes):
        raise ValueError(f"{len(ids)} cropped surface id(s) but {len(boxes)} crop box(es): give one box per "
                         "cropped surface")
    if len(set(ids)) != len(ids):
        raise ValueError(f"a surface is cropped twice in {ids}: give one box per surface")
    return {int(i): box_from_ros(b, f"crop box for surface {i}") for i, b in zip(ids, boxes)}
