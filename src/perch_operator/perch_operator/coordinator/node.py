"""perch_operator node: /perch/crop, the /perch/plan_perches coordinator, /perch/confirm, waypoints.

One process hosts all three because the confirm service acts on the coordinator's live
proposals (a rejection re-optimises with the mission's regions and target), and crop is
light; crop is still called through its service so it is recorded and replayable like any stage.
"""

from __future__ import annotations

import sys
import threading
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from geometry_msgs.msg import PoseArray
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import GoalEvent, RCLError
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from unique_identifier_msgs.msg import UUID
from visualization_msgs.msg import Marker, MarkerArray

from perch_common.conventions import CONFIRM_SERVICE, MISSION_ACTION, STAGE_SERVICES
from perch_common.errors import PerchError
from perch_common.memory import release_memory
from perch_common.mesh import MeshError, validate_mesh
from perch_common.ros.conversions import (
    cached_mesh_to_msg,
    id_only_msg,
    is_id_only,
    mesh_from_msg,
    mesh_from_request,
    target_from_msg,
    target_to_msg,
    to_array,
)
from perch_common.ros.marker_wire import serialized_marker
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config, read_config
from perch_common.ros.service import answering, create_stage_service
from perch_common.ros.static_transforms import StaticTransformPublisher, alignment_to_msg, transform_msg
from perch_common.transforms import parse_up_axis, pose_to_matrix
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_interfaces.action import PlanPerches
from perch_operator.coordinator.config import OperatorConfig
from perch_operator.coordinator.crop import crop_mesh
from perch_operator.coordinator.goal_watch import GoalWatch
from perch_operator.coordinator.markers import camera_frame, current_picture, scan_marker, scene_markers
from perch_operator.coordinator.messages import box_from_ros, pose_array_msg, proposal_msg, waypoint_msg, waypoint_set_msg
from perch_operator.coordinator.mission import Mission, MissionOptions, Operator, decide
from perch_operator.coordinator.proposals import Decision, Proposal, ProposalError, Status
from perch_operator.coordinator.review import ReviewDecision, ReviewDesk, review_crops, review_outlines
from perch_operator.coordinator.stages import MissionCancelled, StageCaller, StageError
from perch_operator.coordinator.views import camera_info_msg, image_msg, render_proposal_view
from perch_operator.outputs.mission_data import placement_config

# Late joiners (a dispatcher started after the mission, a UI) still get every waypoint/proposal.
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Simulated views: enough for one mission's proposals; a deeper history kept every mission's images
# (~170 KB each) in the writer, the operator's RSS growing for 50 missions.
VIEWS_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=16, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
LATCHED_LAST = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)


class OperatorNode(Node):
    """Serves crop, the plan_perches action, confirm and surface review; publishes proposals and waypoints."""

    def __init__(self) -> None:
        super().__init__("perch_operator")
        self.config = declare_config(self, OperatorConfig, check=OperatorConfig.validate)
        self.static_transforms = StaticTransformPublisher(self)
        group = ReentrantCallbackGroup()
        self.stages = StageCaller(self, group, self.config.service_wait, self.config.stage_timeout,
                                  self.config.gone_grace)
        self.crop_service = create_stage_service(self, srv.Crop, STAGE_SERVICES["crop"], self._crop,
                                                 self.config.introspection, callback_group=group)
        self.confirm_service = self.create_service(srv.Confirm, CONFIRM_SERVICE, self._confirm,
                                                   callback_group=group)
        self.review_service = self.create_service(srv.ReviewSurfaces, "perch/review_surfaces", self._review_decided,
                                                  callback_group=group)
        self.review_pub = self.create_publisher(pm.SurfaceReview, "perch/surface_review", LATCHED_LAST)
        self.review_desk = ReviewDesk()
        self.proposals_pub = self.create_publisher(pm.Proposal, "perch/proposals", LATCHED)
        self.waypoints_pub = self.create_publisher(pm.PerchWaypoint, "perch/waypoints", LATCHED)
        self.poses_pub = self.create_publisher(PoseArray, "perch/waypoint_poses", LATCHED_LAST)
        # Exactly the current mission's accepted waypoints (a late dispatcher never sees older missions').
        self.waypoint_set_pub = self.create_publisher(pm.PerchWaypointSet, "perch/mission_waypoints", LATCHED_LAST)
        self._mission_id = UUID()
        # What an RViz/Foxglove user sees of the mission (latched: a late viewer gets the current picture).
        self.markers_pub = self.create_publisher(MarkerArray, "perch/markers", LATCHED_LAST)
        self._shown: dict[int, pm.Proposal] = {}  # the current mission's proposals as last published
        self._camera = None
        self._scene_markers: tuple[tuple, list] | None = None   # (what they show, markers): built once a mission
        # Each proposal's simulated view (latched, one per proposal: a late viewer gets them all).
        self.view_pub = self.create_publisher(Image, "perch/views/image", VIEWS_LATCHED)
        self.view_info_pub = self.create_publisher(CameraInfo, "perch/views/camera_info", VIEWS_LATCHED)
        self._view_scene = None
        # Viewers: the scan as one decimated, coloured TRIANGLE_LIST, and each drone's own view topics
        # (perch/views/drone_N/image, camera_info: an image panel per drone), latched.
        self.scan_pub = self.create_publisher(Marker, "perch/scan_marker", LATCHED_LAST)
        self._scan_shown = False  # this mission's scan marker has gone to the view thread
        self._drone_view_pubs: dict[int, tuple] = {}
        # Views are rendered in order on their own thread: a view is a picture for the operator, and
        # no decision (nor an auto-accepted mission's result) waits for it. It runs at the stages' own
        # priority: at niceness 15 a loaded machine drew a mission's views after its recording had ended.
        self._view_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="perch-views")
        # The current mission's view work not yet done: a new mission drops what is still queued, which
        # otherwise held every earlier mission's meshes while the views lagged behind the missions (the
        # coordinator's RSS grew ~2 meshes a mission on a loaded machine).
        self._view_work: list = []
        self._view_lock = threading.Lock()
        self.action = ActionServer(self, PlanPerches, MISSION_ACTION, self._execute, callback_group=group,
                                   goal_callback=self._on_goal, cancel_callback=self._on_cancel)
        # A networked graph's mission cancel: signed, on the stage-cancel topic (see _on_mission_cancel).
        from perch_common.network_auth import ReplayGuard
        from perch_common.ros.service import CANCEL_TOPIC

        self._running_goal = None   # the running mission's goal handle
        self._cancels_taken = ReplayGuard()
        self.create_subscription(pm.StageCancel, CANCEL_TOPIC, self._on_mission_cancel, 10, callback_group=group)
        self.operator: Operator | None = None
        # Progress inside a long stage: the reconstruction's frame counters become mission feedback.
        self._running_mission: Mission | None = None
        self.create_subscription(pm.ReconstructionProgress, "perch/reconstruct/progress",
                                 self._on_reconstruct_progress, 10, callback_group=group)
        self._mission_state = ""   # the current mission's: running, succeeded, failed or cancelled
        self._busy = threading.Lock()
        self._next_proposal_id = 1
        self.get_logger().info("ready: /perch/crop, /perch/plan_perches, /perch/confirm, /perch/review_surfaces")

    def destroy_node(self) -> None:
        """Destroy the action server too: rclpy's destroy_node leaves action servers alive, and a
        destroyed coordinator's server (in a process that goes on, e.g. after a one-process graph
        stopped) would keep accepting goals from the graph that nobody serves. Views not yet
        rendered are dropped (the one being rendered finishes first)."""
        self._view_worker.shutdown(wait=True, cancel_futures=True)
        self.action.destroy()
        super().destroy_node()

    # --- crop ---------------------------------------------------------------------------------

    @answering
    def _crop(self, request: srv.Crop.Request, response: srv.Crop.Response) -> srv.Crop.Response:
        config = read_config(self, OperatorConfig).crop
        mesh = validate_mesh(mesh_from_request(request.mesh, "crop mesh"), "crop mesh")
        keep = [box_from_ros(b, f"keep box {i}") for i, b in enumerate(request.keep_boxes)]
        remove = [box_from_ros(b, f"remove box {i}") for i, b in enumerate(request.remove_boxes)]
        result = crop_mesh(mesh, keep, remove, target_from_msg(request.target), config)
        if len(result.kept_faces) == mesh.num_faces:   # nothing cropped: name the caller's mesh, do not echo it
            response.mesh = id_only_msg(request.mesh)
        else:
            response.mesh = cached_mesh_to_msg(result.mesh, stamp=request.mesh.header.stamp)
        if request.return_kept_faces:   # only when asked: on a 1M-face mesh they weigh as much as its triangles / 3
            response.kept_faces = to_array(result.kept_faces, np.uint32)
        response.target = target_to_msg(result.target)
        response.success = True
        kind = "box" if result.target.is_box else f"footprint x {result.target.height:.2f} m"
        response.message = (f"kept {result.mesh.num_faces} of {mesh.num_faces} faces; target {kind}, "
                            f"{result.target.volume():.2f} m^3")
        return response

    # --- mission ------------------------------------------------------------------------------

    def _on_goal(self, goal) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning("rejecting a goal: a mission is already running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _on_cancel(self, goal_handle) -> CancelResponse:
        """Cancel requests are accepted on a host-only graph. A networked graph cannot authenticate the
        action's standard cancel (it has no room for a token): it refuses it and takes the signed cancel
        (_on_mission_cancel) that `perch plan`'s Ctrl-C, `perch operator cancel` and
        PerchCommander.cancelMission send under --network."""
        from perch_common.network_auth import networked

        if networked():
            self.get_logger().error("refused an unsigned mission cancel: a networked graph takes signed cancels only "
                                    "(`perch operator cancel` with the graph's key, PERCH_NETWORK=1)")
            return CancelResponse.REJECT
        return CancelResponse.ACCEPT

    def _on_mission_cancel(self, msg: pm.StageCancel) -> str:
        """The signed mission cancel: a StageCancel naming the mission action and the mission's goal id
        (request_id, hex), with an HMAC token over both and the reason (perch_common.network_auth, as
        for stage calls). Taken once (a replayed token is refused) and only for the mission running now;
        unsigned ones only on a host-only graph. Stage cancels on the same topic are StageWork's.
        Returns why it was refused ('' when taken)."""
        from perch_common.network_auth import networked, refusal_if_networked

        if msg.service.strip("/") != MISSION_ACTION:
            return "not a mission cancel"
        refused = refusal_if_networked(msg.auth, "stage_cancel", msg.service, msg.request_id, msg.reason)
        handle = self._running_goal
        if not refused and networked():
            refused = self._cancels_taken.refusal(msg.auth)
        if not refused and (handle is None or self._mission_text() != msg.request_id):
            refused = (f"mission {msg.request_id or '(none named)'} is not running"
                       + (f" (mission {self._mission_text()} is)" if handle is not None else ""))
        if refused:
            self.get_logger().error(f"refused a mission cancel: {refused}")
            return refused
        try:   # what the action server does with a cancel it accepts: the goal is now CANCELING
            handle._update_state(GoalEvent.CANCEL_GOAL)
        except RCLError:
            return "the mission ended meanwhile"
        self.get_logger().warning(f"mission {msg.request_id}: cancel taken ({msg.reason or 'no reason given'})")
        return ""

    def _signed(self, msg: pm.PerchWaypointSet) -> pm.PerchWaypointSet:
        """The set with the coordinator's token when the graph is networked (the dispatcher checks it)."""
        from perch_common.network_auth import sign_if_networked, waypoint_set_fields

        if hasattr(msg, "auth"):
            msg.auth = sign_if_networked("waypoints", *waypoint_set_fields(msg))
        return msg

    def _execute(self, goal_handle) -> PlanPerches.Result:
        with self._busy:
            try:
                return self._run_mission(goal_handle)
            except Exception as exc:   # a fault of the coordinator's own: the client still gets a reason, not ""
                self.get_logger().error(f"mission failed: internal error: {traceback.format_exc()}")
                if goal_handle.is_active:
                    goal_handle.abort()
                return PlanPerches.Result(success=False, message=f"internal error: {type(exc).__name__}: {exc}")
            finally:
                # The action server keeps finished goals (with their requests) for result_timeout;
                # drop the mesh so that memory does not grow with every mission. Re-planning keeps
                # its own reference to what it needs.
                goal_handle.request.mesh = pm.TriangleMesh()
                # Once the mission's views are drawn, hand the freed heap back (glibc keeps it per
                # thread arena otherwise: the coordinator's RSS crept up for ~20 missions).
                self._view_worker.submit(release_memory)

    def _submit_view(self, work, *args) -> None:
        """Queue view work (scan marker, a proposal's view) for the view thread, as this mission's."""
        with self._view_lock:
            self._view_work = [f for f in self._view_work if not f.done()] + [self._view_worker.submit(work, *args)]

    def _drop_earlier_views(self) -> int:
        """Cancel the view work of earlier missions still queued (a new mission's picture replaces theirs);
        how many were dropped."""
        with self._view_lock:
            dropped = sum(f.cancel() for f in self._view_work)
            self._view_work = []
        return dropped

    def _run_mission(self, goal_handle) -> PlanPerches.Result:
        config = read_config(self, OperatorConfig)
        dropped = self._drop_earlier_views()
        if dropped:
            self.get_logger().info(f"dropped {dropped} views of the previous mission not yet drawn")
        self._mission_id = UUID(uuid=goal_handle.goal_id.uuid)
        self.operator, self._mission_state = None, "running"   # decisions now bind to this mission only
        self._shown, self._camera, self._view_scene, self._scene_markers = {}, None, None, None
        self._scan_shown = False
        self.waypoint_set_pub.publish(self._signed(waypoint_set_msg(self._mission_id, [], self._frame_id(),
                                                                    self.get_clock().now().to_msg())))
        options = MissionOptions(
            auto_accept=config.auto_accept, exclusion_radius=config.exclusion_radius,
            clean_given_mesh=config.clean_given_mesh, optimise_on_full_mesh=config.optimise_on_full_mesh,
            confirm_timeout=config.confirm_timeout, frame_id=self._frame_id(),
            up=parse_up_axis(config.up_axis), input_up=config.input_up_axis)

        def feedback(stage: str, fraction: float, message: str, stage_fraction: float = 0.0) -> None:
            sent = PlanPerches.Feedback(stage=stage, fraction=fraction, message=message)
            if stage_fraction:   # set only inside a stage that reports its own progress
                sent.stage_fraction = stage_fraction
            goal_handle.publish_feedback(sent)

        def adopt(operator: Operator) -> None:
            self.operator = operator

        self.stages.service_wait, self.stages.timeout = config.service_wait, config.stage_timeout
        self.stages.gone_grace = config.gone_grace
        watch = GoalWatch(self, config.client_grace, bytes(goal_handle.goal_id.uuid))

        def cancelled() -> bool:
            return goal_handle.is_cancel_requested or watch.gone()

        def review(surfaces: list, opened: Callable[[int], None]) -> ReviewDecision:
            review_id = self.review_desk.open([s.id for s in surfaces], review_outlines(surfaces))
            self.review_pub.publish(pm.SurfaceReview(review_id=review_id, surfaces=surfaces))
            opened(review_id)
            rejected = self.review_desk.wait(review_id, config.confirm_timeout, cancelled)
            return ReviewDecision(rejected, self.review_desk.crops(review_id))

        def aligned(alignment) -> None:  # the input frame -> gravity-aligned frame, for tf users
            self.static_transforms.send(alignment_to_msg(alignment))

        def input_frame(frame_id: str) -> None:
            given = goal_handle.request.mesh   # the scan for viewers, early: it is in the input frame already
            if len(given.triangles) and not self._scan_shown:
                self._scan_shown = True
                self._submit_view(self._publish_scan, given, np.eye(4), frame_id)

        mission = Mission(self.stages, options, self._next_proposal_id, feedback, cancelled,
                          self._publish_proposal, adopt, review, aligned, input_frame)
        self._running_mission, self._running_goal = mission, goal_handle
        try:
            result = mission.run(goal_handle.request)
            result.waypoints = [self._waypoint(p) for p in self.operator.book.accepted()]
            goal_handle.succeed()
            self._mission_state = "succeeded"
            self.get_logger().info(f"mission done: {result.message}, "
                                   + ", ".join(f"{n} {s:.2f} s" for n, s in zip(result.stage_names,
                                                                                 result.stage_seconds)))
            return result
        except MissionCancelled as exc:
            if watch.gone() and not goal_handle.is_cancel_requested:
                goal_handle.abort()
                self.get_logger().error(f"mission aborted: {watch.describe()}")
                return self._failed(mission, f"{watch.describe()} ({exc})")
            goal_handle.canceled()
            self.get_logger().warning(f"mission cancelled: {exc}")
            return self._failed(mission, str(exc))
        except (StageError, PerchError, MeshError, ValueError, TimeoutError, OSError) as exc:
            goal_handle.abort()
            message = str(exc) + mission.up_hint(exc) + mission.clean_hint()
            self.get_logger().error(f"mission failed: {message}")
            return self._failed(mission, message)
        finally:
            self._running_mission = self._running_goal = None
            if self._mission_state == "running":
                self._mission_state = "cancelled" if goal_handle.is_cancel_requested else "failed"
            if self.operator is not None:
                self._next_proposal_id = self.operator.book.next_id

    def _on_reconstruct_progress(self, msg: pm.ReconstructionProgress) -> None:
        mission = self._running_mission
        if mission is not None and msg.mode == msg.MODE_BAG and msg.frames_total:
            mission.stage_progress("reconstruct", msg.frames_received / msg.frames_total,
                                   f"frames {msg.frames_received}/{msg.frames_total} read, "
                                   f"{msg.frames_integrated} integrated")

    @staticmethod
    def _failed(mission: Mission, message: str) -> PlanPerches.Result:
        # What the mission noted on the way (what a damaged bag lost) may be why it failed: said with it.
        message += "".join(f"; {note}" for note in mission.notes if note)
        return PlanPerches.Result(success=False, message=message, stage_names=mission.stage_names,
                                  stage_seconds=mission.stage_seconds)

    # --- operator -----------------------------------------------------------------------------

    def _unbound(self, request: srv.Confirm.Request) -> str:
        """Why a decision does not bind to the current mission ('' when it does): decisions are taken
        while the mission runs; once it succeeded only an accepted perch failing in flight is reported (and
        the replacement its re-plan proposes is decided)."""
        if self.operator is None or not self._mission_state:
            return (f"no mission has proposed anything (proposal {request.proposal_id} is unknown)"
                    if not self._mission_state or self._mission_state == "running" else
                    f"mission {self._mission_text()} {self._mission_state} before proposing anything; "
                    f"proposal {request.proposal_id} is unknown")
        if self._mission_state == "running":
            return ""
        if self._mission_state != "succeeded":
            return (f"mission {self._mission_text()} {self._mission_state}: its proposals were never dispatched, "
                    "decisions on them are refused; run a new mission")
        if request.decision != srv.Confirm.Request.FAILED_IN_FLIGHT and not self._open_replacement(request.proposal_id):
            return (f"mission {self._mission_text()} has ended (succeeded): only an accepted perch failing in flight "
                    "can still be reported, and its replacement decided; run a new mission to decide again")
        return ""

    def _open_replacement(self, proposal_id: int) -> bool:
        """An undecided proposal of the succeeded mission: the replacement a failed-in-flight re-plan made."""
        from perch_operator.coordinator.proposals import ProposalError, Status

        try:
            return self.operator.book.get(proposal_id).status == Status.PENDING
        except ProposalError:
            return False

    def _mission_text(self) -> str:
        return bytes(bytearray(self._mission_id.uuid)).hex()

    def _confirm(self, request: srv.Confirm.Request, response: srv.Confirm.Response) -> srv.Confirm.Response:
        from perch_common.network_auth import refusal_if_networked

        refused = refusal_if_networked(getattr(request, "auth", ""), "confirm", request.proposal_id,
                                       request.decision, request.reason) or self._unbound(request)
        if refused:
            response.success, response.message = False, refused
            self.get_logger().warning(f"confirm refused: {refused}")
            return response
        try:
            outcome = decide(self.stages, self.operator, request.proposal_id, Decision(request.decision),
                             request.reason, self._publish_proposal)
            response.success, response.message = True, outcome.message
            if outcome.replacement is not None:
                response.replacement = proposal_msg(outcome.replacement, self.operator.alignment,
                                                    self.operator.optimise_request.regions, self._mission_id)
        except (ProposalError, ValueError) as exc:
            response.success, response.message = False, str(exc)
        except (StageError, PerchError, TimeoutError) as exc:
            response.success, response.message = False, f"re-optimising failed: {exc}"
        return response

    def _review_decided(self, request: srv.ReviewSurfaces.Request,
                        response: srv.ReviewSurfaces.Response) -> srv.ReviewSurfaces.Response:
        try:
            crops = review_crops(request)
            rejected = self.review_desk.decide(request.review_id, list(request.rejected_surface_ids), crops)
            response.success = True
            response.message = (f"surface review {request.review_id}: "
                                + (f"rejected {sorted(rejected)}" if rejected else "all approved")
                                + (f", cropped {sorted(crops)}" if crops else "")
                                + (f" ({request.reason})" if request.reason else ""))
        except ValueError as exc:   # ReviewError, or a crop box that is no box
            response.success, response.message = False, str(exc)
        self.get_logger().info(response.message)
        return response

    def _publish_proposal(self, *proposals: Proposal) -> None:
        """Publish proposal events (in order): each proposal, a new one's view, an accepted one's
        camera frame and waypoint; then, once for them all, the picture and the accepted set."""
        # Proposals exist only once optimise has run, so the mission's operator (and its alignment) is set.
        alignment, config = self.operator.alignment, read_config(self, OperatorConfig)
        regions = self.operator.optimise_request.regions
        cameras = []
        for proposal in proposals:
            published = proposal_msg(proposal, alignment, regions, self._mission_id)
            self.proposals_pub.publish(published)
            if published.id not in self._shown:
                self._submit_view(self._publish_view, proposal, self.operator.optimise_request)
            self._shown[published.id] = published
            if proposal.status == Status.ACCEPTED:
                # the accepted camera's optical frame (z forward, x right, y down) for tf users and viewers
                cameras.append(transform_msg(alignment.input_frame, camera_frame(proposal.slot),
                                             pose_to_matrix(published.placement.camera_pose)))
                self.waypoints_pub.publish(self._waypoint(proposal, config))
        self._publish_markers()
        if cameras:
            self.static_transforms.send(*cameras)
            stamp = self.get_clock().now().to_msg()
            self.poses_pub.publish(pose_array_msg(self.operator.book.accepted(), alignment, stamp))
        if any(p.status != Status.PENDING for p in proposals):  # the accepted set may have gained or lost a perch
            self.waypoint_set_pub.publish(self._signed(waypoint_set_msg(
                self._mission_id, [self._waypoint(p, config) for p in self.operator.book.accepted()],
                alignment.input_frame, self.get_clock().now().to_msg())))

    def _publish_markers(self) -> None:
        """The whole current picture (regions, target, every proposal with frustum and label)."""
        request = self.operator.optimise_request
        if self._camera is None:  # the camera the placement stage used: the request's, else its configuration
            self._camera = request.camera if request.camera.specified else placement_config().camera
        operator, stamp = self.operator, self.get_clock().now().to_msg()
        shown = (request, operator.alignment, operator.surfaces, operator.removals)  # the same objects all mission
        if self._scene_markers is None or any(a is not b for a, b in zip(self._scene_markers[0], shown)):
            if not self._scan_shown:   # a reconstructed scan: the mission's mesh (on the view thread)
                self._scan_shown = True
                self._submit_view(self._publish_scan, request.mesh, operator.alignment.to_input(),
                                         operator.alignment.input_frame)
            self._scene_markers = shown, scene_markers(list(request.regions), request.target,
                                                       operator.alignment.to_input(), operator.alignment.input_frame,
                                                       stamp, operator.surfaces, operator.removals)
        self.markers_pub.publish(current_picture(list(self._shown.values()), self._camera,
                                                 operator.alignment.input_frame, stamp, self._scene_markers[1]))

    def _publish_view(self, proposal: Proposal, request: srv.Optimise.Request) -> None:
        """The new proposal's simulated camera view (Image + CameraInfo in its drone's camera frame),
        of the optimise request that placed it (on the view thread)."""
        try:
            if self._view_scene is None or self._view_scene[0] is not request:   # one mesh and BVH per request
                from perch_placement.core import scene_for

                mesh = mesh_from_request(request.mesh, "mission mesh")
                # the renderer's camera model (what the placement stage assumes), read once per request
                self._view_scene = request, mesh, scene_for(mesh), placement_config().camera
            _, mesh, scene, camera = self._view_scene
            rgb = render_proposal_view(mesh, scene, proposal.placement, camera, target_from_msg(request.target))
        except Exception as exc:  # noqa: BLE001 - a view is a picture: the mission goes on, the log says why
            self.get_logger().warning(f"no simulated view for proposal {proposal.id}: {type(exc).__name__}: {exc}")
            return
        stamp, frame = self.get_clock().now().to_msg(), camera_frame(proposal.slot)
        info, image = camera_info_msg(camera, rgb.shape[1], rgb.shape[0], frame, stamp), image_msg(rgb, frame, stamp)
        self.view_info_pub.publish(info)
        self.view_pub.publish(image)
        if proposal.slot not in self._drone_view_pubs:
            prefix = f"perch/views/drone_{proposal.slot}"
            self._drone_view_pubs[proposal.slot] = (self.create_publisher(Image, f"{prefix}/image", LATCHED_LAST),
                                                    self.create_publisher(CameraInfo, f"{prefix}/camera_info",
                                                                          LATCHED_LAST))
        image_pub, info_pub = self._drone_view_pubs[proposal.slot]
        info_pub.publish(info)
        image_pub.publish(image)

    def _publish_scan(self, mesh_msg: pm.TriangleMesh, to_input: np.ndarray, frame_id: str) -> None:
        """The mission's scan for viewers (perch/scan_marker, decimated, on the view thread), in the input frame."""
        try:
            # A picture: a mesh that travels with its arrays is decoded, not hashed and kept in the stages' cache.
            mesh = mesh_from_request(mesh_msg, "mission mesh") if is_id_only(mesh_msg) else mesh_from_msg(mesh_msg)
            parts = scan_marker(mesh, to_input, frame_id, self.get_clock().now().to_msg())
            marker = serialized_marker(*parts) if parts is not None else None
        except Exception as exc:  # noqa: BLE001 - a picture: the mission goes on, the log says why
            self.get_logger().warning(f"no scan marker: {type(exc).__name__}: {exc}")
            return
        if marker is not None:
            self.scan_pub.publish(marker)

    def _waypoint(self, proposal: Proposal, config: OperatorConfig | None = None) -> pm.PerchWaypoint:
        config = config or read_config(self, OperatorConfig)
        return waypoint_msg(proposal, config.approach_distance, self.operator.alignment,
                            self.get_clock().now().to_msg(), self._mission_id)

    def _frame_id(self) -> str:
        return read_config(self, OperatorConfig).frame_id


COMPONENT = OperatorNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_operator node until Ctrl-C."""
    # Enough threads for: the mission, a confirm call re-optimising, and the replies they wait on.
    return run_node(lambda: OperatorNode(), args, threads=6)


if __name__ == "__main__":
    sys.exit(main())
