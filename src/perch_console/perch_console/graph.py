"""The console's client of the running graph: the same action, services and topics as any other node.

Subscribes to the operator's latched topics (proposals, markers, scan, views, surface review, the
mission's waypoint set, /tf_static) and to the filter's and optimise's service events (what each filter
removed, the shortfall sentence), follows every mission's feedback, and sends goals, confirmations
and review decisions. Everything it hears goes into a `MissionPicture`; `on_change` tells the UI.
"""

from __future__ import annotations

import threading
import uuid
from pathlib import Path
from typing import Callable

import numpy as np
from action_msgs.msg import GoalStatus, GoalStatusArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_action_status_default
from sensor_msgs.msg import CameraInfo, Image
from unique_identifier_msgs.msg import UUID
from visualization_msgs.msg import Marker, MarkerArray

from perch_common.conventions import CONFIRM_SERVICE, MISSION_ACTION, MISSION_FEEDBACK_TOPIC, MISSION_STATUS_TOPIC
from perch_common.ros.spinning import keep_spinning
from perch_common.ros.static_transforms import TF_STATIC_QOS, TF_STATIC_TOPIC, matrix_from_transform
from perch_console.state import MissionPicture, shortfall_of
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_interfaces.action import PlanPerches
from perch_operator.api.presence import ClientPresence
from perch_operator.coordinator.action_client import RegisteringActionClient
from perch_operator.coordinator.node import LATCHED, LATCHED_LAST
from tf2_msgs.msg import TFMessage

EVENTS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
CALL_TIMEOUT = 60.0   # s: a confirm may re-optimise


class ConsoleGraph:
    """A node `perch_console` on its own executor thread, feeding `picture` and calling the graph."""

    def __init__(self, on_change: Callable[[str], None], name: str = "perch_console"):
        self.picture = MissionPicture()
        self._own_goal = False               # the running mission is this console's (its result comes to us)
        self.lock = threading.RLock()        # guards picture
        self.on_change = on_change           # called with what changed: "scan", "markers", "proposals", ...
        self.scan: Marker | None = None
        self.markers: MarkerArray | None = None
        self.node = Node(name)
        self._presence = ClientPresence(self.node)   # while its own mission runs: the coordinator's sign of it
        group = ReentrantCallbackGroup()
        sub = self.node.create_subscription
        sub(pm.Proposal, "perch/proposals", self._on_proposal, LATCHED, callback_group=group)
        sub(MarkerArray, "perch/markers", self._on_markers, LATCHED_LAST, callback_group=group)
        sub(Marker, "perch/scan_marker", self._on_scan, LATCHED_LAST, callback_group=group)
        sub(Image, "perch/views/image", self._on_view, LATCHED, callback_group=group)
        sub(CameraInfo, "perch/views/camera_info", self._on_view_info, LATCHED, callback_group=group)
        sub(pm.SurfaceReview, "perch/surface_review", self._on_review, LATCHED_LAST, callback_group=group)
        sub(pm.PerchWaypointSet, "perch/mission_waypoints", self._on_waypoints, LATCHED_LAST, callback_group=group)
        sub(TFMessage, TF_STATIC_TOPIC, self._on_tf, TF_STATIC_QOS, callback_group=group)
        sub(PlanPerches.Impl.FeedbackMessage, MISSION_FEEDBACK_TOPIC, self._on_feedback, EVENTS, callback_group=group)
        sub(GoalStatusArray, MISSION_STATUS_TOPIC, self._on_status, qos_profile_action_status_default,
            callback_group=group)
        sub(srv.Filter.Event, "perch/filter/_service_event", self._on_filter_event, EVENTS, callback_group=group)
        sub(srv.Optimise.Event, "perch/optimise/_service_event", self._on_optimise_event, EVENTS,
            callback_group=group)
        # rclpy Jazzy's ActionClient drops an answer that overtakes its request's registration (rclpy#1123);
        # the console sends from the UI thread while the executor spins (a CI rehearsal waited 180 s for an
        # acceptance so dropped): one lock over each send and its registration, in a group of its own.
        self.mission = RegisteringActionClient(self.node, PlanPerches, MISSION_ACTION,
                                               callback_group=MutuallyExclusiveCallbackGroup())
        self.confirm = self.node.create_client(srv.Confirm, CONFIRM_SERVICE, callback_group=group)
        self.review = self.node.create_client(srv.ReviewSurfaces, "perch/review_surfaces", callback_group=group)
        self.executor = MultiThreadedExecutor(num_threads=3)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=keep_spinning, args=(self.executor,), name="perch-console-ros", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop spinning and destroy the node."""
        self.executor.shutdown()
        self.mission.destroy()
        self.node.destroy_node()

    # --- what the graph says ------------------------------------------------------------------

    def _changed(self, what: str) -> None:
        with self.lock:
            self.picture.version += 1
        self.on_change(what)

    def _on_proposal(self, msg: pm.Proposal) -> None:
        with self.lock:
            self.picture.proposals[msg.id] = msg
        self._changed("proposals")

    def _on_markers(self, msg: MarkerArray) -> None:
        self.markers = msg
        self._changed("markers")

    def _on_scan(self, msg: Marker) -> None:
        self.scan = msg
        self._changed("scan")

    def _on_view(self, msg: Image) -> None:
        slot = _slot_of(msg.header.frame_id)
        if slot is None or msg.encoding != "rgb8":
            return
        rgb = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, :3 * msg.width]
        with self.lock:
            self.picture.views[slot] = rgb.reshape(msg.height, msg.width, 3).copy()
        self._changed("views")

    def _on_view_info(self, msg: CameraInfo) -> None:
        slot = _slot_of(msg.header.frame_id)
        if slot is None or msg.k[4] <= 0:
            return
        with self.lock:
            self.picture.view_fov[slot] = (2 * np.arctan2(msg.height / 2, msg.k[4]), msg.width / max(msg.height, 1))

    def _on_review(self, msg: pm.SurfaceReview) -> None:
        with self.lock:
            if msg.review_id in self.picture.reviewed:
                return
            self.picture.review = msg
        self._changed("review")

    def _on_waypoints(self, msg: pm.PerchWaypointSet) -> None:
        with self.lock:
            self.picture.waypoints = list(msg.waypoints)
        self._changed("waypoints")

    def _on_tf(self, msg: TFMessage) -> None:
        for transform in msg.transforms:
            if transform.child_frame_id.endswith("_gravity_aligned"):   # input frame -> stages' frame
                with self.lock:
                    self.picture.to_input = matrix_from_transform(transform)

    def _on_feedback(self, msg) -> None:
        with self.lock:
            if not self.picture.running:   # a mission another client started
                self.picture.mission_started()
            self.picture.stage, self.picture.fraction = msg.feedback.stage, float(msg.feedback.fraction)
            self.picture.message = msg.feedback.message
        self._changed("progress")

    def _on_status(self, msg: GoalStatusArray) -> None:
        """A mission another client started ends: its goal's status turns terminal (ours: _on_result)."""
        ended = {GoalStatus.STATUS_SUCCEEDED: "done", GoalStatus.STATUS_ABORTED: "failed",
                 GoalStatus.STATUS_CANCELED: "cancelled"}
        latest = msg.status_list[-1] if msg.status_list else None
        if latest is None or latest.status not in ended:
            return
        with self.lock:
            if not self.picture.running or self._own_goal:
                return
            self.picture.running, self.picture.stage = False, ended[latest.status]
            self.picture.fraction = 1.0 if latest.status == GoalStatus.STATUS_SUCCEEDED else self.picture.fraction
            self.picture.message = ""
        self._changed("progress")

    def _on_filter_event(self, msg) -> None:
        if msg.response:
            with self.lock:
                self.picture.removals = list(msg.response[0].removals)
            self._changed("removals")

    def _on_optimise_event(self, msg) -> None:
        if msg.response and msg.response[0].success:
            with self.lock:
                sentence = shortfall_of(msg.response[0].message)
                if sentence or not self.picture.shortfall:
                    self.picture.shortfall = sentence
            self._changed("progress")

    def show_recording(self, path) -> int:
        """Feed a mission's run.mcap into the picture, as if the graph were publishing it now (the
        scan, markers, proposals, views, review, waypoints, frames, removals); returns the messages read."""
        from perch_operator.outputs.runfile import iter_messages

        handlers = {"/perch/scan_marker": self._on_scan, "/perch/markers": self._on_markers,
                    "/perch/proposals": self._on_proposal, "/perch/views/image": self._on_view,
                    "/perch/views/camera_info": self._on_view_info, "/perch/mission_waypoints": self._on_waypoints,
                    "/tf_static": self._on_tf, "/perch/filter/_service_event": self._on_filter_event,
                    "/perch/optimise/_service_event": self._on_optimise_event}
        count = 0
        for topic, msg, _ in iter_messages(path, list(handlers)):
            handlers[topic](msg)
            count += 1
        with self.lock:
            self.picture.stage, self.picture.fraction = f"recording {Path(path).name}", 1.0
        self._changed("progress")
        return count

    # --- what the console asks ----------------------------------------------------------------

    def start_mission(self, goal: PlanPerches.Goal) -> str:
        """Send the goal; returns '' once accepted, else why not. The result arrives in picture.result."""
        if not self.mission.wait_for_server(timeout_sec=5.0):
            return f"no mission coordinator answers on /{MISSION_ACTION}: is the graph running (perch launch)?"
        with self.lock:
            self.picture.mission_started()
            self._own_goal = True
        self._changed("progress")
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        self._presence.announce(goal_id.uuid)
        sent = self.mission.send_goal_async(goal, goal_uuid=goal_id)
        if not _wait(sent, 30.0):
            self._presence.withdraw()   # told "not answered": should the goal still start, it is nobody's
            return "the coordinator did not answer the goal within 30 s"
        handle = sent.result()
        if not handle.accepted:
            self._presence.withdraw()
            with self.lock:
                self.picture.running, self.picture.stage, self._own_goal = False, "idle", False
            self._changed("progress")
            return "the coordinator refused the goal: a mission is already running"
        handle.get_result_async().add_done_callback(self._on_result)
        return ""

    def _on_result(self, future) -> None:
        self._presence.withdraw()   # before the mission shows as ended: a next start announces its own
        result = future.result().result
        with self.lock:
            self.picture.running, self._own_goal = False, False
            self.picture.stage, self.picture.fraction = ("done", 1.0) if result.success else ("failed", 0.0)
            self.picture.result, self.picture.message = result.message, ""
        self._changed("progress")

    def call_confirm(self, proposal_id: int, decision: int, reason: str) -> tuple[bool, str]:
        """/perch/confirm for one proposal; (success, message)."""
        reply = self._call(self.confirm, srv.Confirm.Request(proposal_id=proposal_id, decision=decision,
                                                             reason=reason))
        return reply.success, reply.message

    def call_review(self, review_id: int, rejected: list[int], reason: str,
                    crops: dict[int, pm.OrientedBox] | None = None) -> tuple[bool, str]:
        """/perch/review_surfaces: the review decided (surfaces not rejected are approved, those in
        `crops` trimmed to their box, input frame)."""
        crops = crops or {}
        reply = self._call(self.review, srv.ReviewSurfaces.Request(
            review_id=review_id, rejected_surface_ids=rejected, reason=reason,
            cropped_surface_ids=list(crops), crop_boxes=list(crops.values())))
        if reply.success:
            with self.lock:
                self.picture.reviewed.add(review_id)
                self.picture.review = None
            self._changed("review")
        return reply.success, reply.message

    def _call(self, client, request):
        if not client.wait_for_service(timeout_sec=5.0):
            raise RuntimeError(f"{client.srv_name} is not offered: is the graph running?")
        future = client.call_async(request)
        if not _wait(future, CALL_TIMEOUT):
            raise TimeoutError(f"{client.srv_name} did not answer within {CALL_TIMEOUT:.0f} s")
        return future.result()


def _wait(future, timeout: float) -> bool:
    """Block (not spinning: the executor thread does) until the future is done; False on timeout."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    return done.wait(timeout)


def _slot_of(frame_id: str) -> int | None:
    """The drone slot of `perch_drone_N_camera_optical`."""
    parts = frame_id.split("_")
    if len(parts) >= 3 and parts[0] == "perch" and parts[1] == "drone" and parts[2].isdigit():
        return int(parts[2])
    return None
