"""Start-up objects are frozen out of garbage collection; what comes later is still collected."""

import gc
import weakref

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
