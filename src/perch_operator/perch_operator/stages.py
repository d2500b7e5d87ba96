"""Calling the stage services from the coordinator: waits, timeouts, vanished servers, failures.

Every failure becomes a StageError whose message names the stage and its service, so the
mission result says which stage to look at.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

from perch_common.errors import PerchError
from perch_interfaces import srv


@dataclass(frozen=True)
class Stage:
    name: str
    service: str
    srv_type: type


STAGES = {s.name: s for s in (
    Stage("reconstruct", "/perch/reconstruct", srv.Reconstruct),
    Stage("clean", "/perch/clean_mesh", srv.CleanMesh),
    Stage("crop", "/perch/crop", srv.Crop),
    Stage("segment", "/perch/segment", srv.Segment),
    Stage("filter", "/perch/filter", srv.Filter),
    Stage("optimise", "/perch/optimise", srv.Optimise),
)}


class StageError(PerchError):
    def __init__(self, stage: str, message: str):
        super().__init__(f"stage {stage} ({STAGES[stage].service}): {message}")
        self.stage = stage


class MissionCancelled(PerchError):
    pass


class StageCaller:
    """One client per stage service on `node`; `call` blocks the calling thread (not the executor)."""

    def __init__(self, node, callback_group, service_wait: float, timeout: float, gone_grace: float):
        self.node = node
        self.service_wait = service_wait
        self.timeout = timeout
        self.gone_grace = gone_grace
        self.clients = {name: node.create_client(s.srv_type, s.service, callback_group=callback_group)
                        for name, s in STAGES.items()}

    def call(self, stage: str, request, cancelled: Callable[[], bool] = lambda: False):
        """The stage's successful reply; raises StageError (or MissionCancelled)."""
        client = self.clients[stage]
        if not client.wait_for_service(timeout_sec=self.service_wait):
            raise StageError(stage, f"service not available within {self.service_wait:.0f} s; is its node "
                                    "running? (`perch launch` starts the graph)")
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + self.timeout
        gone_since = None
        while not done.wait(0.05):
            now = time.monotonic()
            if cancelled():
                client.remove_pending_request(future)
                raise MissionCancelled(f"mission cancelled during stage {stage}")
            if not client.service_is_ready():
                gone_since = gone_since or now
                if now - gone_since > self.gone_grace:
                    client.remove_pending_request(future)
                    raise StageError(stage, "the service disappeared during the call (its node stopped or "
                                            "crashed); restart it and run the mission again")
            else:
                gone_since = None
            if now > deadline:
                client.remove_pending_request(future)
                raise StageError(stage, f"no reply within {self.timeout:.0f} s (parameter stage_timeout)")
        response = future.result()
        if response is None:
            raise StageError(stage, "the call ended without a reply")
        if not response.success:
            raise StageError(stage, f"failed: {response.message}")
        return response
