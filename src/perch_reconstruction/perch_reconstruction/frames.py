"""RGB-D frames, camera intrinsics, and TUM/7-Scenes-style frame folders."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from perch_common.errors import PerchError

# Indoor RGB-D sensors see at most ~10 m; a median this far means the depth is not in the units we think.
MAX_PLAUSIBLE_MEDIAN_DEPTH_M = 20.0
MIN_PLAUSIBLE_MEDIAN_DEPTH_M = 0.05


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the depth camera (colour assumed registered to depth)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics of the image resized by `factor` (pixel centres kept)."""
        return Intrinsics(int(round(self.width * factor)), int(round(self.height * factor)),
                          self.fx * factor, self.fy * factor,
                          (self.cx + 0.5) * factor - 0.5, (self.cy + 0.5) * factor - 0.5)

    @staticmethod
    def from_matrix(k: np.ndarray, width: int, height: int) -> "Intrinsics":
        """Intrinsics from a 3x3 camera matrix and the image size."""
        k = np.asarray(k, np.float64).reshape(3, 3)
        return Intrinsics(int(width), int(height), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))


@dataclass
class RGBDFrame:
    """One synchronised frame: colour (H,W,3) uint8 RGB, depth (H,W) float32 metres (0 = invalid)."""

    color: np.ndarray
    depth: np.ndarray
    stamp_ns: int
    pose: np.ndarray | None = None  # 4x4 world-from-camera (optical frame), when recorded


def check_depth(depth_m: np.ndarray, what: str) -> None:
    """Raise PerchError when depth values cannot be metres of an indoor scene."""
    valid = depth_m[(depth_m > 0) & np.isfinite(depth_m)]
    if valid.size == 0:
        return  # an all-invalid frame integrates nothing; not an error
    median = float(np.median(valid))
    if median > MAX_PLAUSIBLE_MEDIAN_DEPTH_M or median < MIN_PLAUSIBLE_MEDIAN_DEPTH_M:
        raise PerchError(
            f"{what}: median depth {median:.4g} m is implausible for a room (expected "
            f"{MIN_PLAUSIBLE_MEDIAN_DEPTH_M}-{MAX_PLAUSIBLE_MEDIAN_DEPTH_M} m); check the depth units "
            "(16UC1 must be millimetres, 32FC1 metres) or set depth_scale")


COLOR_SUFFIXES = (".color.jpg", ".color.png", ".color.jpeg", ".rgb.jpg", ".rgb.png", ".rgb.jpeg")
_FRAME_RE = re.compile(r"^(?P<stem>.*?)(?P<index>\d+)\.(?:color|rgb)\.(?:jpg|jpeg|png)$", re.IGNORECASE)


@dataclass
class FrameFolder:
    """A folder of `frame-NNNNNN.color.jpg`, `.depth.png` (uint16 mm), optional `.pose.txt` (4x4
    camera-to-world), `camera-intrinsics.txt` (3x3 K) and optional `gravity-direction.txt` (world)."""

    root: Path
    stems: list[str]
    intrinsics: Intrinsics
    gravity: np.ndarray | None
    has_poses: bool
    frames_without_pose_file: int = 0   # of a folder with poses: frames whose .pose.txt is missing

    def __len__(self) -> int:
        return len(self.stems)

    def load(self, index: int, stamp_ns: int = 0) -> RGBDFrame:
        """Frame `index` of the folder: colour, depth and the pose when the folder has one."""
        import cv2

        stem = self.root / self.stems[index]
        color_path = next((p for p in (stem.with_name(stem.name + s) for s in COLOR_SUFFIXES) if p.is_file()), None)
        depth_path = stem.with_name(stem.name + ".depth.png")
        color = cv2.imread(str(color_path)) if color_path else None
        depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
        if color is None:
            raise PerchError(f"{stem}.color.jpg/png: missing or unreadable colour image")
        if depth is None or depth.dtype != np.uint16 or depth.ndim != 2:
            raise PerchError(f"{depth_path}: missing, unreadable or not a 16-bit single-channel PNG (mm)")
        if color.shape[:2] != depth.shape:
            raise PerchError(f"{stem}: colour {color.shape[1]}x{color.shape[0]} and depth "
                             f"{depth.shape[1]}x{depth.shape[0]} differ in size; register them first")
        pose = None
        pose_path = stem.with_name(stem.name + ".pose.txt")
        if self.has_poses and pose_path.is_file():   # a missing one: a frame without a pose, as a lost one
            pose = read_matrix(pose_path, (4, 4), "4x4 camera-to-world pose")
            if not np.isfinite(pose).all():
                pose = None  # the 7-Scenes/TUM convention for a lost-tracking frame
        # 65535 marks invalid Kinect depth; both it and 0 become 0 (invalid).
        depth_m = np.where(depth == 65535, 0, depth).astype(np.float32) / 1000.0
        return RGBDFrame(np.ascontiguousarray(color[:, :, ::-1]), depth_m, stamp_ns, pose)


def read_matrix(path: Path, shape: tuple[int, ...], what: str) -> np.ndarray:
    """A whitespace-separated numeric text file of `shape`; PerchError naming the file otherwise."""
    try:
        values = np.loadtxt(path, ndmin=1)
    except (ValueError, OSError) as exc:
        raise PerchError(f"{path}: cannot be read as a {what} ({exc})") from None
    if values.size != int(np.prod(shape)):
        raise PerchError(f"{path}: holds {values.size} numbers; a {what} needs {int(np.prod(shape))}")
    return values.reshape(shape)


def open_frame_folder(path: str | Path, limit: int | None = None, step: int = 1) -> FrameFolder:
    """A TUM/7-Scenes-style frame folder (PerchError naming what is missing)."""
    root = Path(path)
    if not root.is_dir():
        raise PerchError(f"{root}: no such frame folder")
    found = []
    for p in root.iterdir():
        m = _FRAME_RE.match(p.name)
        if m:
            found.append((int(m["index"]), p.name.split(".")[0]))
    if not found:
        raise PerchError(f"{root}: no frames named like frame-000000.color.jpg with .depth.png beside them")
    stems = [s for _, s in sorted(found)][::max(1, step)]
    if limit:
        stems = stems[:limit]
    k_path = root / "camera-intrinsics.txt"
    if not k_path.is_file():
        raise PerchError(f"{k_path}: missing (3x3 intrinsic matrix K, whitespace separated)")
    import cv2

    first = cv2.imread(str(root / f"{stems[0]}.depth.png"), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise PerchError(f"{root / stems[0]}.depth.png: missing or unreadable")
    k = read_matrix(k_path, (3, 3), "3x3 intrinsic matrix K")
    if not (np.isfinite(k).all() and k[0, 0] > 0 and k[1, 1] > 0):
        raise PerchError(f"{k_path}: focal lengths fx={k[0, 0]:g}, fy={k[1, 1]:g} must be finite and > 0")
    intrinsics = Intrinsics.from_matrix(k, first.shape[1], first.shape[0])
    gravity = None
    g_path = root / "gravity-direction.txt"
    if g_path.is_file():
        gravity = read_matrix(g_path, (3,), "gravity direction (3 numbers)")
    # Poses of some frames only: those frames go without one (a reconstruction from recorded poses skips
    # them), said by the caller; before, one missing file dropped every frame's pose without a word.
    posed = sum((root / f"{s}.pose.txt").is_file() for s in stems)
    return FrameFolder(root, stems, intrinsics, gravity, posed > 0, len(stems) - posed if posed else 0)


def iter_folder_frames(folder: FrameFolder, fps: float = 30.0, start_ns: int = 0,
                       stamps: list[int] | None = None) -> Iterator[RGBDFrame]:
    """The folder's frames in order, stamped with `stamps` (ns), else at `fps` from `start_ns`."""
    period_ns = int(round(1e9 / fps))
    for i in range(len(folder)):
        yield folder.load(i, stamps[i] if stamps is not None else start_ns + i * period_ns)


TIMESTAMPS_FILE = "timestamps.txt"   # `SECONDS NAME` per line (TUM's rgb.txt layout), NAME a frame's stem or file


def folder_stamps(folder: FrameFolder, fps: float, start_ns: int) -> tuple[list[int], str]:
    """Each frame's stamp (ns) and where they came from: the folder's own timestamps.txt when it has
    one (every frame listed, strictly increasing), else `start_ns` + i / fps."""
    path = folder.root / TIMESTAMPS_FILE
    if not path.is_file():
        period = 1e9 / fps
        return [start_ns + int(round(i * period)) for i in range(len(folder))], \
            f"--start {start_ns / 1e9:.3f} at {fps:g} fps"
    listed: dict[str, int] = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        try:
            seconds = float(words[0])
        except ValueError:
            raise PerchError(f"{path}:{number}: expected 'SECONDS NAME', got '{line.strip()}'") from None
        if len(words) < 2:
            raise PerchError(f"{path}:{number}: expected 'SECONDS NAME', got '{line.strip()}'")
        listed[Path(words[1]).name.split(".")[0]] = int(round(seconds * 1e9))
    missing = [s for s in folder.stems if s not in listed]
    if missing:
        raise PerchError(f"{path}: no time stamp for {len(missing)} frame(s) (first: {missing[0]}); list every "
                         f"frame or remove the file to stamp at --fps from --start")
    stamps = [listed[s] for s in folder.stems]
    if any(b <= a for a, b in zip(stamps, stamps[1:])):
        raise PerchError(f"{path}: time stamps must increase from frame to frame")
    return stamps, path.name


def parse_start(text: str) -> int:
    """`--start`: 'now', Unix seconds, or ISO 8601 (a time without zone is UTC) -> ns since the epoch."""
    import datetime
    import time

    text = text.strip()
    if text.lower() == "now":
        return time.time_ns()
    try:
        return int(round(float(text) * 1e9))
    except ValueError:
        pass
    try:
        when = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise PerchError(f"--start {text!r}: use 'now', Unix seconds or ISO 8601 (2024-05-01T10:00:00Z)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.timezone.utc)
    return int(round(when.timestamp() * 1e9))
