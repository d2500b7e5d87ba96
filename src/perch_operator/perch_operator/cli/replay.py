"""`perch replay RUN.mcap [--check]`: re-send a recorded mission's stage requests to a live graph.

With --check, each live reply is compared with the recorded one (numbers within tolerance,
everything else equal); any difference is printed and makes the check fail. This is how a
changed parameter or a regression in a stage shows up.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from perch_common.errors import PerchError
from perch_operator.cli.diff import Tolerance, diff_messages
from perch_operator.coordinator.stages import STAGES
from perch_operator.outputs.runfile import StageCall, resolve_mesh_ids, stage_calls


@dataclass
class CallOutcome:
    """One replayed stage call: its reply, the time it took and how it differs from the recording."""

    call: StageCall
    index: int
    seconds: float
    differences: list[str] = field(default_factory=list)
    error: str = ""

    @property
    def ok(self) -> bool:
        """Whether the call succeeded and matched the recording."""
        return not self.error and not self.differences


def replay(node, path: str | Path, check: bool = True, tol: Tolerance = Tolerance(),
           stages: list[str] | None = None, timeout: float = 300.0, wait: float = 10.0,
           out=None) -> list[CallOutcome]:
    """Re-send every recorded stage request (in order) and compare the replies when `check`."""
    from perch_common.mcap_read import scan_mcap
    from perch_common.ros.testing import call_service

    out = out or sys.stdout
    damage = scan_mcap(path).damage() if Path(path).is_file() else ""
    if damage:   # a recording cut short (its recorder killed) or with corrupt chunks: replay what is there
        out.write(f"perch: warning: damaged recording, replaying what could be read: {damage}\n")
    calls = [c for c in stage_calls(path) if c.request is not None and (stages is None or c.stage in stages)
             and not _mesh_resend(c)]
    if not calls:
        raise PerchError(f"{path}: no stage requests recorded (were the stage services' introspection "
                         "parameters on when it was recorded?)")
    outcomes: list[CallOutcome] = []
    seen: dict[str, int] = {}
    for call in calls:
        seen[call.stage] = seen.get(call.stage, 0) + 1
        started = time.monotonic()
        outcome = CallOutcome(call, seen[call.stage], 0.0)
        call.request.request_id = ""   # the recorded call's id is that mission's, not this replay's
        try:
            reply = call_service(node, STAGES[call.stage].srv_type, call.service, call.request,
                                 timeout=timeout, wait=wait)
        except TimeoutError as exc:
            outcome.error = f"{exc} (is the graph running? `perch launch`)"
            reply = None
        outcome.seconds = time.monotonic() - started
        if reply is not None:   # a reply naming the request's mesh by id compares as that mesh
            resolve_mesh_ids([StageCall(call.stage, call.service, call.request, reply)])
        if reply is not None and check:
            if call.response is None:
                outcome.error = "no recorded reply to compare with"
            else:
                outcome.differences = diff_messages(call.response, reply, tol)
        outcomes.append(outcome)
        _print_outcome(outcome, check, out)
    return outcomes


def _mesh_resend(call: StageCall) -> bool:
    """A call answered "mesh not cached" (the coordinator sent the arrays next): nothing to replay."""
    from perch_common.mesh_cache import is_mesh_not_cached

    return call.response is not None and not call.response.success and is_mesh_not_cached(call.response.message)


def _print_outcome(o: CallOutcome, check: bool, out) -> None:
    recorded = getattr(o.call.response, "seconds", float("nan")) if o.call.response is not None else float("nan")
    name = f"{o.call.stage} #{o.index}"
    if o.error:
        out.write(f"FAIL  {name:<14} {o.error}\n")
    elif not check:
        out.write(f"sent  {name:<14} {o.seconds:6.2f} s (recorded {recorded:.2f} s)\n")
    elif o.ok:
        out.write(f"ok    {name:<14} reply matches the recording ({o.seconds:.2f} s, recorded {recorded:.2f} s)\n")
    else:
        out.write(f"DIFF  {name:<14} {len(o.differences)} difference(s) from the recording:\n")
        for line in o.differences:
            out.write(f"        {line}\n")
    out.flush()


def summary_line(outcomes: list[CallOutcome], check: bool) -> str:
    """One line summing up a replay (and its comparison when checked)."""
    bad = [o for o in outcomes if not o.ok]
    if not check:
        return f"replayed {len(outcomes)} stage call(s)"
    if not bad:
        return f"replay check passed: {len(outcomes)} stage call(s) match the recording"
    names = ", ".join(f"{o.call.stage} #{o.index}" for o in bad)
    return f"replay check FAILED: {len(bad)} of {len(outcomes)} stage call(s) differ or failed ({names})"
