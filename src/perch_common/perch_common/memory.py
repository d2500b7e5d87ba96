"""Giving memory back to the system after a large request (glibc keeps freed heap pages otherwise)."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
import json
import os
import threading
import time
import tracemalloc
from pathlib import Path

M_TRIM_THRESHOLD = -1            # glibc mallopt parameters
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8
MMAP_THRESHOLD_BYTES = 32 << 20  # allocations of 32 MB and more (a large mesh's arrays) get their own mapping
TRIM_WHILE_WORKING = 64 << 20    # free memory a running call keeps at the heap's top for its next arrays
TRIM_WHEN_IDLE = 128 << 10       # glibc's default: what is freed between calls goes back at once
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
    first touches. A building mission (2.31 M faces, one process) spent 4.7-5.9 s in the kernel when
    every array of 4 MB and more had its own mapping, returned on free (3.0 s and 1.75 M faults with
    numpy's huge pages off, below). Now only arrays of 32 MB and more are mapped; the others come
    from one heap for all threads (one arena:
    malloc_trim gives back a thread arena's free chunks but not its top), whose freed pages the next
    arrays reuse while a call runs (KEEP_FREED_MEMORY): 0.82 M faults, 1.7 s of system time. The
    heap is still trimmed after each stage's reply (release_memory). The fixed values also stop
    glibc's own thresholds from moving with the sizes it sees.

    numpy asks for transparent huge pages for arrays of 4 MB and more (madvise). With the kernel's
    usual defrag=madvise, a fault in such an array compacts memory for a 2 MB page: 800 MB of fresh
    arrays took 4.1 s here against 0.3 s without, and the mission's system time was 4.7 s against 3.0 s.
    Perch's arrays are large and short-lived, so the TLB gain does not pay for it.

    Returns which of the two took effect (False where the C library is not glibc, numpy has no
    switch, or the user set NUMPY_MADVISE_HUGEPAGE).
    """
    libc = _libc()
    heap = libc is not None and all(libc.mallopt(option, value) for option, value in (
        (M_ARENA_MAX, 1), (M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES), (M_TRIM_THRESHOLD, TRIM_WHEN_IDLE)))
    KEEP_FREED_MEMORY.enabled = heap
    huge_pages_off = False
    if HUGE_PAGES_ENV not in os.environ:
        import numpy as np

        switch = getattr(getattr(getattr(np, "_core", None), "multiarray", None), "_set_madvise_hugepage", None)
        if switch is not None:
            switch(False)
            huge_pages_off = True
    return {"heap": heap, "huge_pages_off": huge_pages_off}


class _KeepFreedMemory:
    """`with KEEP_FREED_MEMORY:` around a stage call. While any call of the process runs, memory freed
    at the heap's top stays (up to TRIM_WHILE_WORKING) for the call's next arrays (a building mission:
    0.82 M page faults against 1.14 M, mission 8.1-8.3 s against 8.5-8.7); when none runs, what is
    freed goes back at once, so buffers a transport frees after the reply's trim are not kept (with
    the large threshold between calls too, a stage node kept 24 MB after a 14.5 MB request,
    test_stage_calls). Nothing unless tune_memory set the heap up (glibc)."""

    def __init__(self) -> None:
        self.enabled = False
        self._lock = threading.Lock()
        self._calls = 0

    def __enter__(self) -> None:
        with self._lock:
            self._calls += 1
            if self._calls == 1:
                self._set(TRIM_WHILE_WORKING)

    def __exit__(self, *exc) -> None:
        with self._lock:
            self._calls -= 1
            if self._calls == 0:
                self._set(TRIM_WHEN_IDLE)

    def _set(self, threshold: int) -> None:
        libc = _libc()
        if self.enabled and libc is not None:
            libc.mallopt(M_TRIM_THRESHOLD, threshold)


KEEP_FREED_MEMORY = _KeepFreedMemory()

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
