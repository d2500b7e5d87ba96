"""Start-up objects are frozen out of garbage collection; what comes later is still collected. Freed
memory is reused without page faults and numpy's arrays get no huge pages, unless the user says so."""

import gc
import json
import os
import subprocess
import sys
import weakref

import pytest

from perch_common.memory import freeze_startup_objects


class _Node:
    def __init__(self):
        self.other = None


def test_frozen_start_up_objects_leave_later_garbage_collectable():
    gc.unfreeze()
    try:
        before = _Node()
        before.other = before                       # a live cycle that exists at start-up
        freeze_startup_objects()
        assert gc.get_freeze_count() > 0
        assert len(gc.get_objects(generation=2)) < 100   # nothing left for a full collection to walk
        later = _Node()
        later.other = later                          # garbage made after start-up...
        probe = weakref.ref(later)
        del later
        gc.collect()
        assert probe() is None                       # ...is still collected
        assert before.other is before
    finally:
        gc.unfreeze()


def test_traced_records_show_which_line_grew(tmp_path):
    import json
    import tracemalloc

    from perch_common.memory import record_traced, traced_growth

    was_tracing = tracemalloc.is_tracing()
    if not was_tracing:
        assert record_traced(tmp_path) is None   # an untraced process writes nothing
        tracemalloc.start()
    try:
        before = json.loads(record_traced(tmp_path).read_text())
        held = [bytearray(1 << 20) for _ in range(4)]   # 4 MB held from this line
        after = json.loads(record_traced(tmp_path).read_text())
    finally:
        if not was_tracing:
            tracemalloc.stop()
    growth = traced_growth(before, after, top=1)
    assert growth["growth_mb"] >= 3.9
    (line, kb), = growth["top_lines_kb"].items()
    assert line.endswith("test_memory.py:" + str(_line_of("held = [bytearray")))
    assert kb == pytest.approx(4096, rel=0.01)
    assert len(held) == 4 and not list(tmp_path.glob("*.partial"))


def _line_of(text: str) -> int:
    source = open(__file__).read().splitlines()
    return next(i for i, line in enumerate(source, 1) if text in line and "_line_of" not in line)


_PAGE_FAULTS = """
import json, resource, sys
import numpy as np
from perch_common.memory import KEEP_FREED_MEMORY, tune_memory
settings = tune_memory() if sys.argv[1] == "tuned" else {}
faults = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_minflt
rss = lambda: int(open("/proc/self/statm").read().split()[1]) * resource.getpagesize()
with KEEP_FREED_MEMORY:        # a stage call running
    a = np.ones(16 << 17)      # 16 MB, as a stage's work arrays are
    del a
    before = faults()
    b = np.ones(16 << 17)      # the same size again, every page written
    during_call = faults() - before
    del b
idle = rss()
c = np.ones(16 << 17)          # between calls
del c
print(json.dumps({"faults": during_call, "settings": settings, "kept_when_idle": rss() - idle,
                  "huge_pages_were_on": bool(np._core.multiarray._set_madvise_hugepage(True))}))
"""


def _page_faults(mode: str, **env: str) -> dict:
    environment = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"} | env
    run = subprocess.run([sys.executable, "-c", _PAGE_FAULTS, mode], capture_output=True, text=True,
                         env=environment, timeout=60, check=True)
    return json.loads(run.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc and numpy's madvise: Linux only")
def test_tuned_memory_reuses_freed_pages_in_a_call_returns_them_between_calls_without_huge_pages():
    plain, tuned = _page_faults("plain", NUMPY_MADVISE_HUGEPAGE="0"), _page_faults("tuned")
    pages = (16 << 20) // os.sysconf("SC_PAGE_SIZE")
    # Untuned (and in small pages, to count them), glibc maps the first 16 MB array and unmaps it on
    # free; the second one comes from a heap grown for it: every page is touched for the first time.
    assert plain["faults"] > 0.9 * pages
    assert tuned["settings"] == {"heap": True, "huge_pages_off": True}
    assert tuned["faults"] < 0.05 * pages     # the freed array's pages, reused within the call
    assert tuned["kept_when_idle"] < (1 << 20)  # between calls a freed array goes back at once
    assert _page_faults("plain")["huge_pages_were_on"] and not tuned["huge_pages_were_on"]


def test_a_huge_page_choice_the_user_made_is_kept():
    kept = _page_faults("tuned", NUMPY_MADVISE_HUGEPAGE="1")
    assert kept["settings"]["huge_pages_off"] is False and kept["huge_pages_were_on"]
