"""Turning expected failures into one clear line instead of a traceback."""

from __future__ import annotations

import contextlib
import os
import sys

from perch_common.config import ConfigError
from perch_common.mesh import MeshError


class PerchError(RuntimeError):
    """A failure the user can act on; its message says what happened and what to do."""


EXPECTED = (PerchError, MeshError, ConfigError, ValueError, FileNotFoundError)


@contextlib.contextmanager
def report_errors():
    """Print expected errors as `perch: error: ...` and exit 1 (PERCH_DEBUG=1 shows tracebacks)."""
    try:
        yield
    except EXPECTED as exc:
        if os.environ.get("PERCH_DEBUG"):
            raise
        print(f"perch: error: {exc}", file=sys.stderr)
        sys.exit(1)
