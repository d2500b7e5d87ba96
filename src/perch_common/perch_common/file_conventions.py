"""Which way is up by a file's own convention: its format's specification, or its exporter's name in the header.

OBJ and PLY have no up convention, but their exporters do, and most write their name in a comment:
Unity, Apple's ModelIO/ARKit, HoloLens/Windows Device Portal, RealSense Viewer, 3D Scanner App,
Polycam and Scaniverse all write +y-up files (their worlds are y-up, gravity along -y). A known
exporter in the header is evidence for the up estimate (perch_common.up_axis), not an order: the
file may have been turned upright afterwards (a Unity prefab rotated to z-up, say), and the geometry
can still disagree. glTF/GLB is +y up by its specification. Anything else says nothing (+z is only
the default a user would expect).

The convention travels as text (the PlanPerches goal's `up_convention`): '+y' alone for a format's
or the default convention, '+y (exporter: Unity)' when a header named it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

HEADER_BYTES = 4096     # the comments an exporter writes come first
HEADER_LINES = 40
FORMAT_CONVENTIONS = {".glb": "+y", ".gltf": "+y"}  # glTF 2.0 is +y up by its specification
DEFAULT_CONVENTION = "+z"

# (pattern in a header comment, exporter name, its up axis). Case-insensitive; matched in comment
# lines only (OBJ '#', PLY 'comment'/'obj_info') so that a group named 'unity_chair' does not count.
KNOWN_EXPORTERS: tuple[tuple[str, str, str], ...] = (
    (r"\bunity\b", "Unity", "+y"),
    (r"\bmodel\s?io\b", "ModelIO", "+y"),
    (r"\barkit\b", "ARKit", "+y"),
    (r"\bholo\s?lens\b", "HoloLens", "+y"),
    (r"\bdevice\s+portal\b", "Windows Device Portal", "+y"),
    (r"\breal\s?sense\s+viewer\b", "RealSense Viewer", "+y"),
    (r"\b3d\s+scanner\s+app\b", "3D Scanner App", "+y"),
    (r"\bpolycam\b", "Polycam", "+y"),
    (r"\bscaniverse\b", "Scaniverse", "+y"),
)
_TEXT = re.compile(r"^(?P<axis>[^()]+?)\s*(?:\(exporter:\s*(?P<exporter>[^)]*)\))?\s*$")


@dataclass(frozen=True)
class FileConvention:
    """An up axis a file implies and why: its exporter (evidence), its format, or nothing (default)."""

    axis: str                 # '+y', '+z', ...
    exporter: str = ""        # the exporter named in the header ('' when none)

    @property
    def from_exporter(self) -> bool:
        """True when a known exporter's name in the header implies the axis (evidence for the estimate)."""
        return bool(self.exporter)

    def text(self) -> str:
        """'+y (exporter: Unity)' or '+y': the form PlanPerches' up_convention carries."""
        return f"{self.axis} (exporter: {self.exporter})" if self.exporter else self.axis

    @staticmethod
    def parse(text: str | None) -> "FileConvention":
        """The inverse of text(); empty text is the default convention. ValueError for anything else."""
        match = _TEXT.match((text or "").strip() or DEFAULT_CONVENTION)
        if match is None:
            raise ValueError(f"up convention '{text}': use an axis such as +y, optionally '(exporter: NAME)'")
        return FileConvention(match["axis"].strip(), (match["exporter"] or "").strip())


def header_comments(path: str | Path) -> list[str]:
    """The comment lines at the head of an OBJ or PLY file ('' stripped of its marker); [] for others."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".obj", ".ply") or not path.is_file():
        return []
    with open(path, "rb") as stream:
        head = stream.read(HEADER_BYTES).decode("latin-1").splitlines()[:HEADER_LINES]
    comments = []
    for line in head:
        line = line.strip()
        if suffix == ".obj" and line.startswith("#"):
            comments.append(line[1:].strip())
        elif suffix == ".ply":
            if line == "end_header":
                break
            for marker in ("comment", "obj_info"):
                if line.startswith(marker + " "):
                    comments.append(line[len(marker):].strip())
    return comments


def exporter_convention(comments: list[str]) -> FileConvention | None:
    """The convention of the first known exporter named in these header comments, or None."""
    for comment in comments:
        for pattern, name, axis in KNOWN_EXPORTERS:
            if re.search(pattern, comment, re.IGNORECASE):
                return FileConvention(axis, name)
    return None


def file_convention_of(path: str | Path | None) -> FileConvention:
    """The up convention of a mesh file: a known exporter in its header, else its format's (glTF: +y),
    else the default +z."""
    if not path:
        return FileConvention(DEFAULT_CONVENTION)
    try:
        found = exporter_convention(header_comments(path))
    except OSError:   # unreadable here: the loader reports it; the convention falls back
        found = None
    return found or FileConvention(FORMAT_CONVENTIONS.get(Path(path).suffix.lower(), DEFAULT_CONVENTION))
