"""Where the shared real data lives (../shared/data beside the repository), if present."""

from __future__ import annotations

import os
from pathlib import Path


def repo_root() -> Path:
    """The workspace root (the folder holding src/ and config/)."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "src").is_dir() and (parent / "config").is_dir():
            return parent
    return Path.cwd()


def shared_data_dir() -> Path | None:
    """PERCH_SHARED_DATA, else ../shared/data beside the repository; None when absent."""
    env = os.environ.get("PERCH_SHARED_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(repo_root().parent / "shared" / "data")
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    return None


def shared_file(*parts: str) -> Path | None:
    """A file under the shared data folder, or None when it (or the folder) is absent."""
    root = shared_data_dir()
    path = root.joinpath(*parts) if root else None
    return path if path is not None and path.exists() else None
