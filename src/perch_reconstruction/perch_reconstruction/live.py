"""Live ingestion: bounded frame queue, explicit drop policy, a worker that integrates (no rclpy).

Callbacks hand over decoded images; pairs go into a queue of `queue_size` frames. When the queue is
full the OLDEST waiting frame is dropped and counted ("queue_full"): integration then follows the
newest view, and memory never exceeds queue_size frames plus the TSDF's block budget.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from typing import Callable

import numpy as np

from perch_common.errors import PerchError
from perch_common.frames import aligned_frame_name
from perch_common.mesh import Mesh
from perch_reconstruction.config import ReconstructionNodeConfig
from perch_reconstruction.core import ReconstructionStats, Reconstructor
from perch_reconstruction.frames import Intrinsics, RGBDFrame
from perch_reconstruction.progress import MODE_LIVE, NO_CAMERA_INFO, QUEUE_FULL, UNPAIRED, ReconstructionProgress
from perch_reconstruction.sync import FrameAssembler, PoseBuffer

QUIET_S = 0.5
MAX_QUIET_WAIT_S = 3.0


class LiveIngest:
    """Live RGB-D input: pairs colour and depth, waits for poses, integrates in a worker thread."""

    def __init__(self, config: ReconstructionNodeConfig, log: Callable[[str], None] = print):
        self.config = config.validate()
        self.log = log
        self._lock = threading.Lock()          # guards the queue, counters, buffers
        self._volume_lock = threading.Lock()   # guards the reconstructor
        self._wake = threading.Condition(self._lock)
        self._queue: deque[RGBDFrame] = deque()
        self._busy = False
        self._stop = False
        self._reset_state()
        self._thread = threading.Thread(target=self._run, name="perch_reconstruction_worker", daemon=True)
        self._thread.start()

    def _reset_state(self) -> None:
        self.recon = Reconstructor(self.config.stage_config(), self.config.use_poses)
        self.assembler = FrameAssembler(int(self.config.sync_tolerance * 1e9), max(8, self.config.queue_size))
        self.poses = PoseBuffer(capacity=100_000)
        self.intrinsics: Intrinsics | None = None
        self.dropped: Counter = Counter()
        self.last_error = ""
        self._first_image_time: float | None = None
        self._last_image_time: float | None = None
        self._queue.clear()

    # --- input ----------------------------------------------------------------------------------
    def on_camera_info(self, intrinsics: Intrinsics) -> None:
        """Take the camera intrinsics."""
        with self._lock:
            self.intrinsics = intrinsics
            self._wake.notify_all()

    def on_pose(self, stamp: int, pose: np.ndarray) -> None:
        """Take one world-from-camera pose."""
        with self._lock:
            self.poses.add(stamp, pose)
            self._wake.notify_all()

    def on_color(self, stamp: int, color: np.ndarray) -> None:
        """Take one colour image."""
        self._offer(lambda: self.assembler.add_color(stamp, color))

    def on_depth(self, stamp: int, depth: np.ndarray) -> None:
        """Take one depth image."""
        self._offer(lambda: self.assembler.add_depth(stamp, depth))

    def _offer(self, pair: Callable[[], RGBDFrame | None]) -> None:
        with self._lock:
            self._last_image_time = time.monotonic()
            if self._first_image_time is None:
                self._first_image_time = self._last_image_time
            before = self.assembler.unpaired_dropped
            frame = pair()
            if self.assembler.unpaired_dropped > before:
                self.dropped[UNPAIRED] += self.assembler.unpaired_dropped - before
            if frame is None:
                return
            if len(self._queue) >= self.config.queue_size:
                self._queue.popleft()
                self.dropped[QUEUE_FULL] += 1
            self._queue.append(frame)
            self._wake.notify_all()

    def report_error(self, message: str) -> None:
        """Log an input error once (until a different one occurs)."""
        with self._lock:
            if message != self.last_error:
                self.log(message)
            self.last_error = message

    # --- worker ---------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._queue and not self._stop:
                    self._wake.wait(0.5)
                if self._stop:
                    return
                frame = self._queue.popleft()
                self._busy = True
            try:
                self._integrate(frame)
            finally:
                with self._lock:
                    self._busy = False
                    self._wake.notify_all()

    def _integrate(self, frame: RGBDFrame) -> None:
        c = self.config
        with self._lock:
            deadline = (self._first_image_time or time.monotonic()) + c.camera_info_timeout
            while self.intrinsics is None and time.monotonic() < deadline and not self._stop:
                self._wake.wait(0.05)
            intrinsics = self.intrinsics
            if intrinsics is None:
                self.dropped[NO_CAMERA_INFO] += 1
                message = (f"no camera info on {c.camera_info_topic} within {c.camera_info_timeout:.1f} s of the "
                           "first image; publish the depth camera's sensor_msgs/CameraInfo there or set "
                           "camera_info_topic")
                if message != self.last_error:
                    self.log(message)
                self.last_error = message
                return
            if c.use_poses:
                deadline = time.monotonic() + c.pose_wait
                tolerance = int(c.pose_tolerance * 1e9)
                while (self.poses.lookup(frame.stamp_ns, tolerance) is None and time.monotonic() < deadline
                       and (self.poses.newest_stamp() or -1) < frame.stamp_ns + tolerance):
                    self._wake.wait(0.02)
                frame.pose = self.poses.lookup(frame.stamp_ns, tolerance)
                if frame.pose is None:
                    newest = self.poses.newest_stamp()
                    message = (f"frame at {frame.stamp_ns / 1e9:.3f} s: no pose on {c.pose_topic} within "
                               f"{c.pose_tolerance} s (newest pose: "
                               f"{'none' if newest is None else f'{newest / 1e9:.3f} s'}); not integrated")
                    if message != self.last_error:
                        self.log(message)
                    self.last_error = message
        try:
            with self._volume_lock:
                self.recon.add_frame(frame, intrinsics, what=c.depth_topic)
        except PerchError as exc:
            self.report_error(f"frame at {frame.stamp_ns / 1e9:.3f} s not integrated: {exc}")

    # --- control --------------------------------------------------------------------------------
    def drain(self, timeout: float, quiet: float = QUIET_S, max_quiet_wait: float = MAX_QUIET_WAIT_S) -> bool:
        """Wait until every queued frame is integrated; False on timeout.

        Frames still in transport (sent, not yet delivered) count too: first wait until no image
        arrived for `quiet` seconds, but at most `max_quiet_wait` (a live stream never goes quiet)."""
        start = time.monotonic()
        deadline = start + timeout
        with self._lock:
            while (self._last_image_time is not None and time.monotonic() - self._last_image_time < quiet
                   and time.monotonic() - start < max_quiet_wait):
                self._wake.wait(0.05)
            while (self._queue or self._busy) and time.monotonic() < deadline:
                self._wake.wait(0.05)
            return not self._queue and not self._busy

    def finish(self, gravity: np.ndarray | None, target_faces: int = 0) -> tuple[Mesh, ReconstructionStats]:
        """Extract and clean what was integrated so far (kept: integration may continue)."""
        with self._volume_lock:
            if target_faces:
                self.recon.config.target_faces = int(target_faces)
            try:
                if self.recon.stats.frames_received == 0:
                    raise PerchError(self._nothing_message())
                mesh = self.recon.finish(gravity, frame_id=self.config.frame_id)
            finally:
                self.recon.config.target_faces = self.config.target_faces
            stats = self.recon.stats
            stats.frames_dropped = self.frames_dropped
            return mesh, stats

    def _nothing_message(self) -> str:
        c = self.config
        if self.last_error:
            return f"nothing integrated: {self.last_error}"
        return (f"nothing integrated: no colour+depth pairs received on {c.color_topic} and {c.depth_topic} "
                f"(stamps must agree within {c.sync_tolerance} s); check the topic names")

    @property
    def frames_dropped(self) -> int:
        """Frames dropped because integration fell behind."""
        return int(sum(self.dropped.values()))

    def reset(self, config: ReconstructionNodeConfig | None = None) -> None:
        """Start over: empty volume, queues and statistics (with `config`'s settings when given)."""
        with self._lock, self._volume_lock:
            if config is not None:
                self.config = config.validate()
            self._reset_state()

    def status(self) -> ReconstructionProgress:
        """Progress counters for the progress topic; the frame is the finished mesh's (gravity-aligned frame_id)."""
        with self._lock:
            return ReconstructionProgress.from_stats(
                MODE_LIVE, self.recon.stats, frame_id=aligned_frame_name(self.config.frame_id),
                dropped=self.dropped, queued=len(self._queue), last_error=self.last_error)

    def stop(self) -> None:
        """Stop the integration thread."""
        with self._lock:
            self._stop = True
            self._wake.notify_all()
        self._thread.join(timeout=5)
