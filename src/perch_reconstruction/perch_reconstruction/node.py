"""perch_reconstruction node: live RGB-D topics or recorded bags in, clean z-up mesh out.

Services: /perch/reconstruct (perch_interfaces/srv/Reconstruct), /perch/reconstruct/reset
(std_srvs/Trigger), /perch/clean_mesh (perch_interfaces/srv/CleanMesh).
Progress: /perch/reconstruct/progress (perch_interfaces/msg/ReconstructionProgress) every progress_period seconds.
"""

from __future__ import annotations

import dataclasses
import sys
import threading

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from perch_common.conventions import STAGE_SERVICES
from perch_common.errors import EXPECTED
from perch_common.frames import Alignment, aligned_frame_name
from perch_common.ros.conversions import cached_mesh_to_msg, mesh_from_request, xyz
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config, read_config
from perch_common.ros.service import answering, create_stage_action, create_stage_service, set_work_budget
from perch_common.ros.static_transforms import StaticTransformPublisher, alignment_to_msg
from perch_common.work import report
from perch_interfaces import action, srv
from perch_interfaces import msg as pm
from perch_reconstruction import images
from perch_reconstruction.bag_write import BagTopics
from perch_reconstruction.cleaning import CleanReport, clean_mesh_with_report
from perch_reconstruction.config import ReconstructionNodeConfig
from perch_reconstruction.core import reconstruct_bag
from perch_reconstruction.live import LiveIngest
from perch_reconstruction.progress import ReconstructionProgress, bag_frame_count, bag_progress
from perch_reconstruction.tf_buffer import TransformBuffer

# ReconstructionProgress fields copied by name (uint32 counters, float64 seconds)
_COUNTERS = ("frames_received", "frames_integrated", "frames_dropped", "frames_without_pose", "frames_lost",
             "frames_over_budget", "queued", "blocks", "faces_raw", "faces")
_SECONDS = ("seconds_integrate", "seconds_track", "seconds_clean")


def progress_to_msg(progress: ReconstructionProgress, stamp) -> pm.ReconstructionProgress:
    """perch_interfaces/msg/ReconstructionProgress of a progress report, stamped `stamp`."""
    msg = pm.ReconstructionProgress(
        mode=progress.mode, bag_path=progress.bag_path, last_error=progress.last_error,
        frames_total=int(progress.frames_total),
        dropped_reasons=list(progress.dropped), dropped_counts=[int(n) for n in progress.dropped.values()],
        **{name: int(getattr(progress, name)) for name in _COUNTERS},
        **{name: float(getattr(progress, name)) for name in _SECONDS})
    msg.header.stamp, msg.header.frame_id = stamp, progress.frame_id
    return msg


def input_qos(lossless: bool, depth: int) -> QoSProfile:
    """Default: best effort, volatile - matches camera drivers (sensor-data QoS) and any player.
    lossless: reliable and transient local, as `perch bag play` offers, so even the first messages
    (sent while discovery completes) arrive; publishers offering volatile durability do not match."""
    if lossless:
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)


class ReconstructionNode(Node):
    """Serves reconstruct, reset and clean_mesh; integrates live RGB-D topics."""

    def __init__(self) -> None:
        super().__init__("perch_reconstruction")
        self.config = declare_config(self, ReconstructionNodeConfig, check=ReconstructionNodeConfig.validate)
        c = self.config
        self.ingest = LiveIngest(c, log=self.get_logger().warning)
        inputs = MutuallyExclusiveCallbackGroup()
        # Poses and camera info in their own group: a burst of images must not hold them back.
        meta = MutuallyExclusiveCallbackGroup()
        services = ReentrantCallbackGroup()
        if c.compressed_images:
            from sensor_msgs.msg import CompressedImage as ImageType
        else:
            from sensor_msgs.msg import Image as ImageType
        from sensor_msgs.msg import CameraInfo

        qos = input_qos(c.lossless_replay, 50 if c.lossless_replay else 10)
        self.create_subscription(ImageType, c.color_topic, self._on_color, qos, callback_group=inputs)
        self.create_subscription(ImageType, c.depth_topic, self._on_depth, qos, callback_group=inputs)
        self.create_subscription(CameraInfo, c.camera_info_topic, self._on_info, input_qos(c.lossless_replay, 10),
                                 callback_group=meta)
        self.tf = TransformBuffer(capacity=10_000)
        self._tf_pending: list[int] = []   # stamps of moving transforms not yet turned into poses
        self._tf_lock = threading.Lock()
        if c.pose_type == "tf":   # poses as robots publish them: the camera's chain in /tf and /tf_static
            from tf2_msgs.msg import TFMessage

            self.create_subscription(TFMessage, "tf", lambda m: self._on_tf(m, False),
                                     input_qos(c.lossless_replay, 100), callback_group=meta)
            self.create_subscription(TFMessage, "tf_static", lambda m: self._on_tf(m, True),
                                     QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                                                durability=DurabilityPolicy.TRANSIENT_LOCAL), callback_group=meta)
        elif c.pose_topic:
            if c.pose_type == "odometry":
                from nav_msgs.msg import Odometry as PoseType
            else:
                from geometry_msgs.msg import PoseStamped as PoseType
            self.create_subscription(PoseType, c.pose_topic, self._on_pose, input_qos(c.lossless_replay, 100),
                                     callback_group=meta)
        self.progress = self.create_publisher(pm.ReconstructionProgress, "perch/reconstruct/progress", 10)
        self.static_transforms = StaticTransformPublisher(self)
        self.create_timer(c.progress_period, self._publish_status, callback_group=meta)
        self._offline_status: ReconstructionProgress | None = None  # the bag a Reconstruct call works on
        self._frame_ids: dict[str, str] = {}
        self._frame_warned = False
        for srv_type, name, callback in ((srv.Reconstruct, STAGE_SERVICES["reconstruct"], self._reconstruct),
                                         (Trigger, "perch/reconstruct/reset", self._reset),
                                         (srv.CleanMesh, STAGE_SERVICES["clean"], self._clean)):
            create_stage_service(self, srv_type, name, callback, c.introspection, callback_group=services)
        self.reconstruct_action = create_stage_action(self, action.Reconstruct, srv.Reconstruct,
                                                      STAGE_SERVICES["reconstruct"], self._reconstruct,
                                                      result_timeout=c.action_server_result_timeout)
        self.get_logger().info(f"ready: /perch/reconstruct, /perch/clean_mesh; listening on {c.color_topic}, "
                               f"{c.depth_topic}, {c.camera_info_topic}" + (", /tf" if c.pose_type == "tf" else
                                                                            f", {c.pose_topic}" if c.pose_topic else ""))

    # --- live input -----------------------------------------------------------------------------
    def _guard(self, topic: str, work) -> None:
        try:
            work()
        except EXPECTED as exc:
            self.ingest.report_error(f"{topic}: {exc}" if topic not in str(exc) else str(exc))

    def _on_color(self, msg) -> None:
        t = self.config.color_topic
        self._check_frames(color=msg.header.frame_id)
        if self._tf_pending:
            with self._tf_lock:
                self._poses_from_tf()
        self._guard(t, lambda: self.ingest.on_color(images.stamp_ns(msg), images.color_from_msg(msg, t)))

    def _on_depth(self, msg) -> None:
        t = self.config.depth_topic
        self._check_frames(depth=msg.header.frame_id)
        self._guard(t, lambda: self.ingest.on_depth(
            images.stamp_ns(msg), images.depth_from_msg(msg, t, self.config.depth_scale)))

    def _check_frames(self, **frame_id: str) -> None:
        """Registered depth carries the colour camera's frame id; different ids mean it is not."""
        self._frame_ids.update(frame_id)
        color, depth = self._frame_ids.get("color"), self._frame_ids.get("depth")
        if color and depth and color != depth and not self._frame_warned:
            self._frame_warned = True
            c = self.config
            self.ingest.report_error(
                f"{c.depth_topic} is in frame '{depth}' but {c.color_topic} in '{color}': depth must be "
                "registered to colour (use the driver's aligned-depth topic); integrating, colours may be offset")

    def _on_info(self, msg) -> None:
        t = self.config.camera_info_topic
        self._guard(t, lambda: self.ingest.on_camera_info(images.intrinsics_from_camera_info(msg, t)))

    def _on_pose(self, msg) -> None:
        self.ingest.on_pose(images.stamp_ns(msg), images.pose_from_msg(msg))

    def _on_tf(self, msg, static: bool) -> None:
        """Keep the transforms; each moving one gives the camera's pose at its stamp (when the chain
        from the camera frame up to tf_world_frame is complete)."""
        with self._tf_lock:   # colour images (another callback group) may turn pending stamps into poses
            self.tf.add_message(msg, static)
            if not static:
                self._tf_pending.extend(sorted({images.stamp_ns(t) for t in msg.transforms}))
                del self._tf_pending[:-1000]   # bounded while the camera frame is not known yet
                self._poses_from_tf()

    def _poses_from_tf(self) -> None:
        c = self.config
        camera = c.tf_camera_frame or self._frame_ids.get("color", "")
        if not camera or self.tf.chain(c.tf_world_frame, camera) is None:
            return   # kept until the images' frame (first colour image) and the mount (/tf_static) are known
        tolerance = int(c.pose_tolerance * 1e9)
        for stamp in self._tf_pending:
            pose = self.tf.lookup(c.tf_world_frame, camera, stamp, tolerance)
            if pose is not None:
                self.ingest.on_pose(stamp, pose)
        self._tf_pending.clear()

    def _publish_status(self) -> None:
        status = self._offline_status or self.ingest.status()
        self.progress.publish(progress_to_msg(status, self.get_clock().now().to_msg()))

    # --- services -------------------------------------------------------------------------------
    def current_config(self) -> ReconstructionNodeConfig:
        """The parameters now (a change while running applies to the next call; read-only ones never change)."""
        return read_config(self, ReconstructionNodeConfig)

    @answering
    def _reconstruct(self, request, response):
        c = self.current_config()
        try:
            if request.bag_path:
                mesh, stats = self._reconstruct_bag(request)
            else:
                response.frames_dropped = self.ingest.frames_dropped
                if not self.ingest.drain(c.drain_timeout):
                    self.get_logger().warning(f"frames still queued after {c.drain_timeout} s; extracting anyway")
                gravity = np.asarray(c.gravity, np.float64)
                mesh, stats = self.ingest.finish(gravity if np.any(gravity) else None, int(request.target_faces))
        finally:
            self._offline_status = None
        response.mesh = cached_mesh_to_msg(mesh, self.get_clock().now().to_msg())
        self._answer_alignment(response, stats.frame_id, stats.clean)
        response.frames_integrated, response.frames_dropped = stats.frames_integrated, stats.frames_dropped
        response.success = True
        response.message = (f"{mesh.num_faces} faces from {stats.frames_integrated} of {stats.frames_received}"
                            f" frames ({stats.frames_dropped} dropped, {stats.frames_without_pose} without pose, "
                            f"{stats.frames_lost} lost, {stats.frames_over_budget} over the block budget)")
        if stats.clean is not None:
            response.message += f"; up from {stats.clean.up_source}"
            if stats.clean.warnings:
                response.message += "; " + "; ".join(stats.clean.warnings)
        return response

    def _reconstruct_bag(self, request):
        c = self.current_config()
        config = c.stage_config()
        if request.target_faces:
            config = dataclasses.replace(config, target_faces=int(request.target_faces))
        topics = BagTopics(c.color_topic, c.depth_topic, c.camera_info_topic, c.pose_topic)

        total = bag_frame_count(request.bag_path, topics)   # for the fraction within the stage
        set_work_budget(self, c, total, "frames", per=1.0, rate=c.work_budget_per_frame,
                        hint="the bag's frames are unusually slow to integrate (image size, voxel_size?)")

        def progress(stats) -> None:
            self._offline_status = bag_progress(request.bag_path, stats, total)
            self._publish_status()   # each checkpoint at once, not only on the timer: a fast bag shows its progress too
            if total:
                report(stats.frames_received / total, "frames")   # perch/stage_progress (perch_common.work)

        self._offline_status = bag_progress(request.bag_path, None, total)  # reading: counters at zero, frame unknown

        return reconstruct_bag(request.bag_path, config, bool(request.use_poses), topics, progress=progress)

    def _reset(self, request, response):
        from perch_common.network_auth import networked

        if networked():   # std_srvs/Trigger has no room for a token (perch_common.network_auth)
            response.success = False
            response.message = ("refused: a networked graph takes no unauthenticated reset; restart the "
                                "perch_reconstruction node to clear its reconstruction")
            self.get_logger().error(f"reset {response.message}")
            return response
        self.ingest.reset(self.current_config())   # live input takes the parameters as they are now
        response.success, response.message = True, "reconstruction cleared"
        self.get_logger().info("reset: volume, queue and counters cleared")
        return response

    @answering
    def _clean(self, request, response):
        current = self.current_config()
        config = current.stage_config()
        if request.target_faces:
            config = dataclasses.replace(config, target_faces=int(request.target_faces))
        gravity = xyz(request.gravity)
        given = mesh_from_request(request.mesh, "mesh to clean")
        set_work_budget(self, current, given.num_faces)
        given.frame_id = request.mesh.header.frame_id or current.frame_id
        mesh, report = clean_mesh_with_report(given, gravity if np.any(gravity) else None, config)
        mesh.frame_id = aligned_frame_name(given.frame_id)
        response.mesh = cached_mesh_to_msg(mesh, self.get_clock().now().to_msg())
        self._answer_alignment(response, given.frame_id, report)
        response.success = True
        response.message = report.summary()
        response.warnings = list(report.warnings)
        return response

    def _answer_alignment(self, response, input_frame: str, report: CleanReport | None) -> None:
        """Fill the reply's alignment (input frame -> gravity-aligned frame) and send it on /tf_static."""
        rotation = np.eye(3) if report is None else report.rotation
        alignment = Alignment(input_frame, rotation, report.up_source if report else "none",
                              report.up_confidence if report else 0.0)
        response.alignment = alignment_to_msg(alignment, self.get_clock().now().to_msg())
        response.up_source, response.up_confidence = alignment.up_source, float(alignment.up_confidence)
        if report is not None and report.up_estimate is not None:
            response.up_evidence = report.up_estimate.evidence()
        if response.alignment.child_frame_id != response.alignment.header.frame_id:
            self.static_transforms.send(response.alignment)

    def destroy_node(self):
        """Stop live integration, then destroy the node."""
        self.ingest.stop()
        return super().destroy_node()


COMPONENT = ReconstructionNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_reconstruction node until Ctrl-C."""
    return run_node(lambda: ReconstructionNode(), args=args, threads=4)


if __name__ == "__main__":
    sys.exit(main())
