"""Pairing colour and depth by time stamp, and looking up poses, with bounded buffers.

Shared by the offline bag reader and the live node, so both integrate the same frames.
"""

from __future__ import annotations

import bisect
from collections import OrderedDict

import numpy as np

from perch_reconstruction.frames import RGBDFrame


class FrameAssembler:
    """Pairs colour and depth images whose stamps differ by at most `tolerance_ns`.

    At most `max_pending` unpaired images per stream are held; older ones are discarded and
    counted in `unpaired_dropped` (a stream without its partner must not grow memory).
    """

    def __init__(self, tolerance_ns: int = 5_000_000, max_pending: int = 8):
        self.tolerance_ns = int(tolerance_ns)
        self.max_pending = int(max_pending)
        self._color: OrderedDict[int, np.ndarray] = OrderedDict()
        self._depth: OrderedDict[int, np.ndarray] = OrderedDict()
        self.unpaired_dropped = 0

    def add_color(self, stamp: int, color: np.ndarray) -> RGBDFrame | None:
        """Add a colour image; the RGB-D frame once its depth partner is there."""
        return self._add(stamp, color, self._color, self._depth, color_first=True)

    def add_depth(self, stamp: int, depth: np.ndarray) -> RGBDFrame | None:
        """Add a depth image; the RGB-D frame once its colour partner is there."""
        return self._add(stamp, depth, self._depth, self._color, color_first=False)

    def _add(self, stamp: int, image: np.ndarray, mine: OrderedDict, other: OrderedDict,
             color_first: bool) -> RGBDFrame | None:
        match = min(other, key=lambda s: abs(s - stamp), default=None)
        if match is not None and abs(match - stamp) <= self.tolerance_ns:
            partner = other.pop(match)
            # Images older than the matched one can no longer pair (streams are time ordered).
            for old in [s for s in other if s < match]:
                del other[old]
                self.unpaired_dropped += 1
            color, depth = (image, partner) if color_first else (partner, image)
            return RGBDFrame(color=color, depth=depth, stamp_ns=min(stamp, match))
        mine[stamp] = image
        while len(mine) > self.max_pending:
            mine.popitem(last=False)
            self.unpaired_dropped += 1
        return None

    def clear(self) -> None:
        """Drop every waiting image."""
        self._color.clear()
        self._depth.clear()


class PoseBuffer:
    """The last `capacity` poses by stamp; `lookup` returns the nearest within a tolerance."""

    def __init__(self, capacity: int = 10_000):
        self.capacity = int(capacity)
        self._stamps: list[int] = []
        self._poses: list[np.ndarray] = []

    def add(self, stamp: int, pose: np.ndarray) -> None:
        """Add one stamped pose."""
        i = bisect.bisect(self._stamps, stamp)
        self._stamps.insert(i, stamp)
        self._poses.insert(i, pose)
        if len(self._stamps) > self.capacity:
            del self._stamps[0], self._poses[0]

    def __len__(self) -> int:
        return len(self._stamps)

    def newest_stamp(self) -> int | None:
        """Stamp of the newest pose, None when empty."""
        return self._stamps[-1] if self._stamps else None

    def lookup(self, stamp: int, tolerance_ns: int) -> np.ndarray | None:
        """The pose stamped closest to `stamp` within the tolerance, None otherwise."""
        i = bisect.bisect_left(self._stamps, stamp)
        best = None
        for j in (i - 1, i):
            if 0 <= j < len(self._stamps) and abs(self._stamps[j] - stamp) <= tolerance_ns:
                if best is None or abs(self._stamps[j] - stamp) < abs(self._stamps[best] - stamp):
                    best = j
        return None if best is None else self._poses[best]

    def clear(self) -> None:
        """Forget every pose."""
        self._stamps.clear()
        self._poses.clear()
