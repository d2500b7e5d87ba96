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
