"""argparse types the commands share: a bad value is refused by name before anything runs."""

from __future__ import annotations

import argparse
import math


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"{text} must be a finite number > 0")
    return value


def xyz(text: str) -> tuple[float, float, float]:
    """Three finite numbers, comma-separated (X,Y,Z)."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give X,Y,Z (three numbers, comma-separated)") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: give X,Y,Z (three finite numbers, comma-separated)")
    return values   # type: ignore[return-value]
