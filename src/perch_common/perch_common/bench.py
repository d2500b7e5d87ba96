"""`perch bench NAME`: benchmarks are plugins in the entry point group `perch.benchmarks`.

Each entry is `register(subparsers)`; its handler prints one JSON object on stdout.
"""

from __future__ import annotations

import json
import resource
import sys


def register(sub) -> None:
    """Add `perch bench` with every installed benchmark (entry points perch.benchmarks) as a subcommand."""
    parser = sub.add_parser("bench", help="run a benchmark and print JSON")
    benches = parser.add_subparsers(dest="bench", metavar="BENCHMARK")
    from perch_common.cli import load_plugins

    load_plugins("perch.benchmarks", benches, level=1)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def emit(result: dict) -> int:
    """Print a benchmark result as JSON (numpy scalars converted)."""
    json.dump(result, sys.stdout, indent=2, default=_plain)
    sys.stdout.write("\n")
    return 0


def _plain(value):
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
