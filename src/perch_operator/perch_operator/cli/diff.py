"""Compare two ROS messages field by field: numbers within tolerance, everything else equal.

Used by `perch replay --check`: a recorded stage reply against the live graph's reply to the
same request. Timing and free-text fields are ignored (they differ from run to run), and a mesh's
content id (a cache key; the arrays it names are compared).
"""

from __future__ import annotations

import array
from dataclasses import dataclass

import numpy as np

# content_id names a mesh's arrays for the caches (perch_common.mesh_cache), which are compared themselves
IGNORED_FIELDS = frozenset({"seconds", "message", "stamp", "content_id"})


@dataclass(frozen=True)
class Tolerance:
    """Relative and absolute tolerance for comparing replayed numbers."""

    rtol: float = 1e-4
    atol: float = 1e-5


def is_message(value) -> bool:
    """Whether a value is a ROS message."""
    return hasattr(value, "get_fields_and_field_types")


def _is_numeric_sequence(value) -> bool:
    if isinstance(value, (array.array, np.ndarray, bytes, bytearray)):
        return True
    return isinstance(value, (list, tuple)) and bool(value) and all(
        isinstance(v, (int, float, bool, np.number)) and not isinstance(v, str) for v in value)


def diff_messages(recorded, replayed, tol: Tolerance = Tolerance(), path: str = "",
                  limit: int = 20) -> list[str]:
    """Human-readable differences (at most `limit`), empty when the messages agree."""
    out: list[str] = []
    _diff(recorded, replayed, tol, path, out, limit)
    if len(out) > limit:
        out = out[:limit] + [f"... and more differences (showing the first {limit})"]
    return out


def _diff(a, b, tol: Tolerance, path: str, out: list[str], limit: int) -> None:
    if len(out) > limit:
        return
    if is_message(a):
        for name in a.get_fields_and_field_types():
            if name not in IGNORED_FIELDS:
                _diff(getattr(a, name), getattr(b, name), tol, f"{path}.{name}" if path else name, out, limit)
        return
    if _is_numeric_sequence(a) or _is_numeric_sequence(b):
        _diff_arrays(np.asarray(a), np.asarray(b), tol, path, out)
        return
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            out.append(f"{path}: {len(a)} recorded, {len(b)} replayed")
            return
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, tol, f"{path}[{i}]", out, limit)
        return
    if isinstance(a, float) or isinstance(b, float):
        if not np.isclose(a, b, rtol=tol.rtol, atol=tol.atol, equal_nan=True):
            out.append(f"{path}: recorded {a:.6g}, replayed {b:.6g} (diff {b - a:+.3g})")
        return
    if a != b:
        out.append(f"{path}: recorded {a!r}, replayed {b!r}")


def _diff_arrays(a: np.ndarray, b: np.ndarray, tol: Tolerance, path: str, out: list[str]) -> None:
    if a.shape != b.shape:
        out.append(f"{path}: {a.size} values recorded, {b.size} replayed")
        return
    if a.size == 0:
        return
    if a.dtype.kind == "f" or b.dtype.kind == "f":
        bad = ~np.isclose(a.astype(np.float64), b.astype(np.float64), rtol=tol.rtol, atol=tol.atol, equal_nan=True)
    else:
        bad = a != b
    if bad.any():
        delta = np.abs(a.astype(np.float64) - b.astype(np.float64))
        worst = int(np.argmax(np.where(bad, delta, -1)))
        out.append(f"{path}: {int(bad.sum())} of {a.size} values differ (worst at [{worst}]: recorded "
                   f"{a.flat[worst]:.6g}, replayed {b.flat[worst]:.6g})")
