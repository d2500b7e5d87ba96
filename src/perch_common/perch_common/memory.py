"""Giving memory back to the system after a large request (glibc keeps freed heap pages otherwise)."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
import json
import os
import time
import tracemalloc
from pathlib import Path

M_MMAP_THRESHOLD = -3            # glibc mallopt parameter
MMAP_THRESHOLD_BYTES = 4 << 20   # allocations of 4 MB and more get their own mapping, unmapped on free


@functools.lru_cache(maxsize=1)
def _libc():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


def limit_heap_growth() -> bool:
    """Serve big allocations (mesh arrays) from their own mappings so freeing them returns the memory.

    glibc raises its mmap threshold after each large free (up to 32 MB), so repeated big requests
    end up on the heap, which it does not shrink; a fixed threshold keeps them mapped. False where
    the C library is not glibc.
    """
    libc = _libc()
    if libc is None:
        return False
    return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


TRACE_DIR_ENV = "PERCH_TRACEMALLOC_DIR"   # with PYTHONTRACEMALLOC=1: where release_memory writes what Python holds
TRACE_LINES = 400                         # source lines kept per record (largest first)


def release_memory() -> None:
    """Collect garbage cycles and return free heap pages to the system (malloc_trim); in a traced
    process (PYTHONTRACEMALLOC and PERCH_TRACEMALLOC_DIR set) also record what Python holds now."""
    gc.collect()
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
    record_traced()


def record_traced(folder: str | Path | None = None) -> Path | None:
    """Write what Python's allocations hold now, by source line, to FOLDER/<pid>-<ns>.json
    ({"total_bytes", "lines": {"file:line": bytes}}); None unless tracemalloc traces this process and a
    folder is given or set in PERCH_TRACEMALLOC_DIR. `perch bench soak --tracemalloc` compares two."""
    folder = folder or os.environ.get(TRACE_DIR_ENV)
    if not folder or not tracemalloc.is_tracing():
        return None
    snapshot = tracemalloc.take_snapshot().filter_traces([tracemalloc.Filter(False, tracemalloc.__file__)])
    stats = snapshot.statistics("lineno")   # without the last record's own leftovers
    lines = {f"{s.traceback[0].filename}:{s.traceback[0].lineno}": s.size for s in stats[:TRACE_LINES]}
    path = Path(folder) / f"{os.getpid()}-{time.time_ns()}.json"
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps({"total_bytes": sum(s.size for s in stats), "lines": lines}))
    partial.replace(path)   # a reader never sees half a record
    return path


def traced_growth(before: dict, after: dict, top: int = 10) -> dict:
    """Two record_traced records compared: total growth in MB and the source lines that grew most (kB)."""
    lines = {k: after["lines"].get(k, 0) - before["lines"].get(k, 0)
             for k in set(before["lines"]) | set(after["lines"])}
    largest = sorted(lines.items(), key=lambda item: -item[1])[:top]
    return {"before_mb": round(before["total_bytes"] / 2**20, 2), "after_mb": round(after["total_bytes"] / 2**20, 2),
            "growth_mb": round((after["total_bytes"] - before["total_bytes"]) / 2**20, 2),
            "top_lines_kb": {k: round(v / 1024, 1) for k, v in largest}}


def freeze_startup_objects() -> None:
    """Exempt what exists once the nodes are up (modules, classes, message types: ~100k objects)
    from every later garbage collection.

    A full collection traverses every tracked object: with the imports of a graph that is 70 ms,
    paid after each stage's reply (`release_memory`) and at every automatic full collection, on
    the mission's critical path in a one-process graph. Everything created later is collected as
    before. No collection first: it finds ~20 unreachable objects at this point and takes 50 ms.
    """
    gc.freeze()
