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

M_TRIM_THRESHOLD = -1            # glibc mallopt parameters
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20  # allocations of 32 MB and more (a large mesh's arrays) get their own mapping
TRIM_THRESHOLD_BYTES = 64 << 20  # free heap kept at its top between trims (release_memory gives it all back)
HUGE_PAGES_ENV = "NUMPY_MADVISE_HUGEPAGE"  # numpy's own switch: a value the user set is kept


@functools.lru_cache(maxsize=1)
def _libc():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


def tune_memory() -> dict[str, bool]:
    """Reuse freed memory within a request and give it back after it; no huge pages for numpy's arrays.

    Every page a process touches for the first time costs a page fault, and a fresh mapping is all
    first touches. A building mission (2.31 M faces, one process) made 1.75 M faults and 3-6 s of
    system time when every array of 4 MB and more had its own mapping, returned on free; with only
    those of 32 MB and more mapped, the others reuse the heap's freed pages: 0.9 M faults, 1.9 s.
    The heap is trimmed after each stage's reply (release_memory, which also returns free pages in
    its middle), so the memory still goes back between requests. The fixed values also stop glibc's
    own threshold from moving with the sizes it sees.

    numpy asks for transparent huge pages for arrays of 4 MB and more (madvise). With the kernel's
    usual defrag=madvise, a fault in such an array compacts memory for a 2 MB page: 800 MB of fresh
    arrays took 4.1 s here against 0.3 s without, and the mission's system time was 4.7 s against 3.0 s.
    Perch's arrays are large and short-lived, so the TLB gain does not pay for it.

    Returns which of the two took effect (False where the C library is not glibc, numpy has no
    switch, or the user set NUMPY_MADVISE_HUGEPAGE).
    """
    libc = _libc()
    heap = libc is not None and bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                                     and libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    huge_pages_off = False
    if HUGE_PAGES_ENV not in os.environ:
        import numpy as np

        switch = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "_set_madvise_hugepage", None)
        if switch is not None:
            switch(False)
            huge_pages_off = True
    return {"heap": heap, "huge_pages_off": huge_pages_off}


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
