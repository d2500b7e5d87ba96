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


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def positive_int(text: str) -> int:
    """An integer >= 1 (a count of runs, faces, missions...)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be an integer >= 1")
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0 (a count where 0 means none, or a seed numpy accepts)."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} must be an integer >= 0")
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"{text} must be a finite number >= 0")
    return value


def int_between(low: int, high: int):
    """The type of an integer from `low` to `high` (both included)."""
    def parse(text: str) -> int:
        value = _integer(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} must be an integer from {low} to {high}")
        return value

    parse.__name__ = f"int_between_{low}_{high}"
    return parse


def float_between(low: float, high: float):
    """The type of a finite number from `low` to `high` (both included)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not low <= value <= high:   # NaN too
            raise argparse.ArgumentTypeError(f"{text} must be a number from {low:g} to {high:g}")
        return value

    parse.__name__ = f"float_between_{low:g}_{high:g}"
    return parse


# perch_common.scene_generator.generate_scene's face size range (m), refused there after parsing.
scene_resolution = float_between(0.02, 0.5)
