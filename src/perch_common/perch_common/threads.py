"""How many threads the native libraries get: applied by each entry point, never on import.

Perch's numpy work is many small (N,3)x(3,3) products: a threaded OpenBLAS makes them up to 40x
slower on a loaded 2-core machine, so BLAS gets one thread. Open3D's OpenMP pool has hung in a
futex when left to size itself, so OpenMP gets at most two. The `perch` command, every node's
main(), the one-process container and the test session call `limit_threads()` first; the launcher
and the test graphs give their child processes `thread_environment()`.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterator, TypeVar

T = TypeVar("T")

BLAS_THREADS = 1
OPENMP_THREADS = min(os.cpu_count() or 1, 2)


def thread_environment(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The thread variables for a child process: those already in `environ` (default: this
    process's) win, the others get Perch's limits."""
    environ = os.environ if environ is None else environ
    return {"OPENBLAS_NUM_THREADS": environ.get("OPENBLAS_NUM_THREADS", str(BLAS_THREADS)),
            "OMP_NUM_THREADS": environ.get("OMP_NUM_THREADS", str(OPENMP_THREADS))}


def limit_threads() -> dict[str, int]:
    """Apply the limits to this process; returns them by library API ('blas', 'openmp').

    Libraries already loaded (numpy's OpenBLAS, by the time an entry point runs) are limited through
    threadpoolctl; the variables are also set, unless the user set them, because OpenMP reads
    OMP_NUM_THREADS once, when Open3D first loads (lazily, after this), and child processes inherit them.
    """
    from threadpoolctl import threadpool_limits

    values = thread_environment()
    for name, value in values.items():
        os.environ.setdefault(name, value)
    limits = {"blas": int(values["OPENBLAS_NUM_THREADS"]), "openmp": int(values["OMP_NUM_THREADS"])}
    threadpool_limits(limits=limits)
    return limits


_threads_override: contextvars.ContextVar[int | None] = contextvars.ContextVar("perch_work_threads", default=None)


def work_threads() -> int:
    """Threads a call spreads its own work over (ray batches, a filter's surfaces): OMP_NUM_THREADS
    (at most 2 from Perch's entry points), or 1 inside `one_thread()`."""
    override = _threads_override.get()
    if override is not None:
        return override
    try:
        return max(1, int(thread_environment()["OMP_NUM_THREADS"]))
    except ValueError:
        return OPENMP_THREADS


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run the block's work on the calling thread only (per thread, a contextvar): a process that
    shares the cores with a second process of the same call must not also split its own work."""
    reset = _threads_override.set(1)
    try:
        yield
    finally:
        _threads_override.reset(reset)


def side_by_side(*work: Callable[[], T]) -> list[T]:
    """[w() for w in work]: the first on the calling thread and the others on threads of their own,
    or one after another where one thread is allowed (`work_threads`). For work that releases the
    GIL (numpy, OpenCV, scipy.ndimage on large arrays); an error in any is raised once all have ended."""
    if len(work) < 2 or work_threads() < 2:
        return [w() for w in work]
    with ThreadPoolExecutor(max_workers=len(work) - 1, thread_name_prefix="perch-side") as pool:
        others = [pool.submit(w) for w in work[1:]]
        first = work[0]()
        return [first] + [f.result() for f in others]
