"""Progress of a reconstruction as typed values (no rclpy): what perch/reconstruct/progress carries.

The node fills perch_interfaces/msg/ReconstructionProgress from a `ReconstructionProgress`; the
mode and drop-reason names here are the message's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from perch_common.frames import aligned_frame_name
from perch_reconstruction.core import ReconstructionStats

MODE_LIVE = "live"  # = ReconstructionProgress.MODE_LIVE: integrating the live topics
MODE_BAG = "bag"    # = ReconstructionProgress.MODE_BAG: reconstructing a bag (a Reconstruct call)

# Why live frames are dropped before integration (the message lists every one, in this order).
QUEUE_FULL = "queue_full"          # the queue was full: the oldest waiting frame went
UNPAIRED = "unpaired"              # colour or depth without a partner within sync_tolerance
NO_CAMERA_INFO = "no_camera_info"  # no camera info within camera_info_timeout of the first image
DROP_REASONS = (QUEUE_FULL, UNPAIRED, NO_CAMERA_INFO)


@dataclass
class ReconstructionProgress:
    """One progress report: counters of the live integration or of the bag being reconstructed."""

    mode: str
    frame_id: str = ""                # the frame the finished mesh will be in; empty while unknown
    bag_path: str = ""
    frames_received: int = 0
    frames_integrated: int = 0
    frames_dropped: int = 0           # sum of `dropped`
    frames_without_pose: int = 0
    frames_lost: int = 0
    frames_over_budget: int = 0
    queued: int = 0
    blocks: int = 0
    faces_raw: int = 0
    faces: int = 0
    seconds_integrate: float = 0.0
    seconds_track: float = 0.0
    seconds_clean: float = 0.0
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))  # reason -> frames
    last_error: str = ""
    frames_total: int = 0             # bag: its colour+depth frames (frames_received counts towards it)

    @classmethod
    def from_stats(cls, mode: str, stats: ReconstructionStats, *, frame_id: str = "", bag_path: str = "",
                   dropped: Mapping[str, int] | None = None, queued: int = 0,
                   last_error: str = "") -> "ReconstructionProgress":
        """The report of `stats`; `dropped` (reason -> frames) is given in DROP_REASONS order, every reason."""
        if mode not in (MODE_LIVE, MODE_BAG):
            raise ValueError(f"progress mode '{mode}': use '{MODE_LIVE}' or '{MODE_BAG}'")
        given = dict(dropped or {})
        unknown = sorted(set(given) - set(DROP_REASONS))
        if unknown:
            raise ValueError(f"drop reasons {unknown}: known reasons are {', '.join(DROP_REASONS)}")
        counts = {reason: int(given.get(reason, 0)) for reason in DROP_REASONS}
        return cls(mode=mode, frame_id=frame_id, bag_path=bag_path, frames_received=stats.frames_received,
                   frames_integrated=stats.frames_integrated, frames_dropped=sum(counts.values()),
                   frames_without_pose=stats.frames_without_pose, frames_lost=stats.frames_lost,
                   frames_over_budget=stats.frames_over_budget, queued=int(queued), blocks=stats.blocks,
                   faces_raw=stats.faces_raw, faces=stats.faces, seconds_integrate=stats.seconds_integrate,
                   seconds_track=stats.seconds_track, seconds_clean=stats.seconds_clean, dropped=counts,
                   last_error=last_error)


def bag_progress(bag_path: str, stats: ReconstructionStats | None = None, frames_total: int = 0) -> ReconstructionProgress:
    """The report of a bag reconstruction; before its frames are read (`stats` None) zeros and no frame."""
    if stats is None:
        return ReconstructionProgress(mode=MODE_BAG, bag_path=bag_path, frames_total=int(frames_total))
    # reconstruct_bag always cleans: the mesh will be in the gravity-aligned frame of the bag's pose frame
    report = ReconstructionProgress.from_stats(MODE_BAG, stats, frame_id=aligned_frame_name(stats.frame_id),
                                               bag_path=bag_path)
    report.frames_total = int(frames_total)
    return report


def bag_frame_count(bag_path: str, topics) -> int:
    """Frames a bag holds for reconstruction (the fewer of its colour and depth images); 0 when unknown."""
    from perch_common.errors import PerchError
    from perch_reconstruction.bag_read import bag_info

    try:
        present = bag_info(bag_path)["topics"]
    except PerchError:
        return 0   # the Reconstruct call itself reports what is wrong with the file
    return min(present.get(topics.color, {}).get("count", 0), present.get(topics.depth, {}).get("count", 0))
