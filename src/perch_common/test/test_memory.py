"""Start-up objects are frozen out of garbage collection; what comes later is still collected."""

import gc
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
