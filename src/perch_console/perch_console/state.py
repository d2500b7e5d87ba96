"""What the console knows and decides, without ROS or a browser: boxes, the mission picture, decisions.

The graph client (perch_console.graph) feeds `MissionPicture` from the graph's topics; the browser UI
(perch_console.ui) reads it and edits `EditBox`es; `DecisionDesk` serialises the decisions of every
browser watching and remembers who made each. All geometry is in the input's own frame.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from perch_common.transforms import matrix_from_quaternion

MIN_BOX_SIZE = 0.05   # m: a box edge the handles cannot shrink below
STATUS_NAMES = ("open", "accepted", "rejected", "failed in flight")   # Proposal.STATUS_* order
DECISIONS = {"accept": 0, "reject": 1, "failed": 2}                   # Confirm.ACCEPT/REJECT/FAILED_IN_FLIGHT


@dataclass
class EditBox:
    """An oriented box the operator drags (centre gizmo) and resizes (corner handle) in the input frame."""

    center: np.ndarray
    size: np.ndarray
    wxyz: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, np.float64).reshape(3)
        self.size = np.maximum(np.asarray(self.size, np.float64).reshape(3), MIN_BOX_SIZE)
        self.wxyz = np.asarray(self.wxyz, np.float64).reshape(4)
        self.wxyz = self.wxyz / np.linalg.norm(self.wxyz)

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation of the box's axes (columns) in the input frame."""
        w, x, y, z = self.wxyz
        return matrix_from_quaternion(np.array([x, y, z, w]))

    def corner(self) -> np.ndarray:
        """The (+x, +y, +z) corner: where the resize handle sits."""
        return self.center + self.rotation @ (self.size / 2)

    def resized_to(self, corner: np.ndarray) -> EditBox:
        """The box with its (+,+,+) corner dragged to `corner`, the opposite corner staying put."""
        opposite = self.center - self.rotation @ (self.size / 2)
        local = self.rotation.T @ (np.asarray(corner, np.float64) - opposite)
        size = np.maximum(local, MIN_BOX_SIZE)
        return EditBox(opposite + self.rotation @ (size / 2), size, self.wxyz)

    def face(self, axis: int, sign: float) -> np.ndarray:
        """The centre of the face on the box's `axis` (0, 1, 2) at side `sign` (+1 or -1): where that
        face's handle sits."""
        return self.center + self.rotation[:, axis] * (sign * self.size[axis] / 2)

    def face_moved(self, axis: int, sign: float, position: np.ndarray) -> EditBox:
        """The box with one face dragged to `position` (only its part along the face's axis counts),
        the opposite face staying put; the box cannot turn inside out (MIN_BOX_SIZE)."""
        direction = self.rotation[:, axis] * sign
        opposite = self.center - direction * (self.size[axis] / 2)
        extent = max(float((np.asarray(position, np.float64) - opposite) @ direction), MIN_BOX_SIZE)
        size = self.size.copy()
        size[axis] = extent
        return EditBox(opposite + direction * (extent / 2), size, self.wxyz)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of the (N,3) points lie inside the box."""
        local = (np.asarray(points, np.float64).reshape(-1, 3) - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.size / 2 + 1e-9, axis=1)

    def describe(self) -> str:
        """`box:CX,CY,CZ,SX,SY,SZ` as `perch plan --target` takes it (the rotation omitted when none)."""
        values = ",".join(f"{v:.2f}" for v in (*self.center, *self.size))
        return f"box:{values}" + ("" if np.allclose(self.wxyz, [1, 0, 0, 0]) else " (rotated)")

    @staticmethod
    def around(vertices: np.ndarray, share: float = 0.4) -> EditBox:
        """A box at the centre of the points' bounds, `share` of their extent on each axis."""
        low, high = np.min(vertices, axis=0), np.max(vertices, axis=0)
        return EditBox((low + high) / 2, (high - low) * share)


FACES = tuple((axis, sign) for axis in range(3) for sign in (1.0, -1.0))   # the six face handles


def surface_box(frame, boundary: list, thickness: float = 0.3) -> EditBox:
    """A box around a surface's outline (plane coordinates of a perch_common PlaneFrame), turned with
    the surface (box x, y, z = its u, v, normal), `thickness` m across the plane: where the console's
    crop box for that surface starts."""
    rings = [np.asarray(ring, np.float64) for polygon in boundary for ring in polygon[:1]]
    uv = np.vstack(rings) if rings else np.zeros((1, 2))
    low, high = uv.min(axis=0), uv.max(axis=0)
    middle = (low + high) / 2
    rotation = np.column_stack([frame.axis_u, frame.axis_v, frame.normal])
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] *= -1
    center = frame.origin + middle[0] * frame.axis_u + middle[1] * frame.axis_v
    return EditBox(center, (*(high - low), thickness), quaternion_wxyz(rotation))


def quaternion_wxyz(rotation: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of a 3x3 rotation."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(rotation, np.float64)).as_quat()
    return np.array([w, x, y, z])


def floor_hit(ray_origin, ray_direction, up, floor_height: float) -> np.ndarray | None:
    """Where a click's ray meets the floor plane (height `floor_height` along `up`); None when it
    runs parallel to the floor or away from it."""
    origin, direction = np.asarray(ray_origin, np.float64), np.asarray(ray_direction, np.float64)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    along = float(direction @ up)
    if abs(along) < 1e-9:
        return None
    distance = (floor_height - float(origin @ up)) / along
    return None if distance <= 0 else origin + distance * direction


def footprint_triangles(points: np.ndarray, up) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (K,3), triangles (M,3)) covering the polygon the clicked floor points outline (in
    click order): what a target footprint mesh carries. ValueError when they outline no area."""
    import shapely

    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) < 3:
        raise ValueError(f"a floor footprint needs at least 3 points, got {len(points)}: click more on the floor")
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    u = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(up, u)
    uv = np.column_stack([points @ u, points @ v])
    polygon = shapely.make_valid(shapely.Polygon(uv))
    if polygon.area < 1e-4:
        raise ValueError("the clicked floor points outline no area: click around the area to watch")
    triangles = shapely.constrained_delaunay_triangles(polygon)
    corners = np.array([np.asarray(t.exterior.coords)[:3] for t in triangles.geoms])
    level = float(np.mean(points @ up))
    flat = corners.reshape(-1, 2)
    vertices = flat[:, :1] * u + flat[:, 1:] * v + level * up
    return vertices, np.arange(len(vertices)).reshape(-1, 3)


@dataclass
class Decision:
    """One decision taken in the console: who, what, on which proposal or review, and the answer."""

    who: str
    what: str
    subject: str
    reason: str
    success: bool
    message: str
    at: float = field(default_factory=time.time)

    def line(self) -> str:
        """'12:04:05 alice rejected proposal 7 (blocks the door): ok'."""
        stamp = time.strftime("%H:%M:%S", time.localtime(self.at))
        because = f" ({self.reason})" if self.reason else ""
        outcome = "ok" if self.success else f"refused: {self.message}"
        return f"{stamp} {self.who} {self.what} {self.subject}{because}: {outcome}"


class DecisionDesk:
    """Serialises decisions from every browser (one at a time, in arrival order) and keeps who decided."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.log: list[Decision] = []
        self.by_proposal: dict[int, Decision] = {}

    def decide(self, who: str, what: str, subject: str, reason: str, call, proposal_id: int | None = None) -> Decision:
        """Run `call()` -> (success, message) under the desk's lock and record it as `who`'s decision."""
        with self._lock:
            try:
                success, message = call()
            except (TimeoutError, RuntimeError, ValueError) as exc:
                success, message = False, str(exc)
            decision = Decision(who, what, subject, reason, bool(success), str(message))
            self.log.append(decision)
            if proposal_id is not None and decision.success:
                self.by_proposal[proposal_id] = decision
            return decision

    def recent(self, count: int = 12) -> list[Decision]:
        """The last `count` decisions, newest first."""
        with self._lock:
            return list(reversed(self.log[-count:]))


@dataclass
class MissionPicture:
    """The current mission as the graph shows it (filled by the graph client, read by the UI)."""

    stage: str = "idle"
    fraction: float = 0.0
    message: str = ""
    shortfall: str = ""
    result: str = ""
    running: bool = False
    proposals: dict = field(default_factory=dict)     # id -> perch_interfaces Proposal (latest)
    views: dict = field(default_factory=dict)         # drone slot -> (H,W,3) uint8 view
    view_fov: dict = field(default_factory=dict)      # drone slot -> (vertical fov rad, aspect)
    removals: list = field(default_factory=list)      # perch_interfaces FilterRemoval of the last filter call
    review: object = None                             # the open perch_interfaces SurfaceReview, if any
    reviewed: set = field(default_factory=set)        # review ids already decided
    waypoints: list = field(default_factory=list)     # the latest PerchWaypointSet's waypoints
    to_input: np.ndarray = field(default_factory=lambda: np.eye(4))   # gravity-aligned -> input frame
    version: int = 0                                  # bumped on every change the UI must show

    def mission_started(self) -> None:
        """Forget the previous mission's proposals, views, review and removals."""
        self.proposals, self.views, self.view_fov, self.removals = {}, {}, {}, []
        self.review, self.shortfall, self.result, self.waypoints = None, "", "", []
        self.stage, self.fraction, self.message, self.running = "starting", 0.0, "", True


def new_token() -> str:
    """A URL-safe secret for an exposed console (`--host`)."""
    return secrets.token_urlsafe(18)


def shortfall_of(optimise_message: str) -> str:
    """The shortfall sentence an optimise reply opens with when fewer cameras fit ('' when all did)."""
    if not optimise_message or optimise_message.startswith("placed "):
        return ""
    return optimise_message.split(". placed ")[0].rstrip(".") + "."


def evidence_lines(evidence) -> str:
    """The perch's safety evidence (its region's worst values) in words, or that it was not measured."""
    if evidence.support_share < 0:
        return "safety evidence not measured"
    return (f"approach clear {evidence.approach_clearance:.2f} m, free fall {evidence.free_fall:.2f} m, "
            f"support {100 * evidence.support_share:.0f} %, flatness {100 * evidence.flatness_rms:.1f} cm RMS")


def removal_table(removals, filter_names: tuple[str, ...], largest: int = 12) -> str:
    """Markdown: what each filter removed from the surfaces that lost most (m^2), largest first."""
    rows = sorted(removals, key=lambda r: r.area_total - r.area_kept, reverse=True)[:largest]
    if not rows:
        return "_no filter run yet_"
    head = "| surface | total | kept | " + " | ".join(n.replace("_", " ") for n in filter_names) + " |"
    rule = "|" + "---|" * (3 + len(filter_names))
    body = [f"| S{r.surface_id} | {r.area_total:.2f} | {r.area_kept:.2f} | "
            + " | ".join(f"{getattr(r, n):.2f}" if getattr(r, n) > 0 else "" for n in filter_names) + " |"
            for r in rows]
    return "\n".join([head, rule, *body])


def waypoint_rows(proposals: dict) -> list[tuple[int, int, float, float, float]]:
    """(proposal id, drone, x, y, z) of every accepted proposal's perch, by id: what the console shows
    as the mission's waypoints."""
    rows = []
    for pid in sorted(proposals):
        p = proposals[pid]
        if p.status == 1:
            position = p.placement.drone_pose.position
            rows.append((int(pid), int(p.placement.drone_index), position.x, position.y, position.z))
    return rows
