"""Reading a recorded mission (MCAP): stage calls from introspection events, topic messages, metadata."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from perch_common.errors import PerchError
from perch_common.ros.msgdefs import message_reader
from perch_common.timing import time_ns
from perch_operator.coordinator.stages import STAGES
from perch_operator.outputs.recorder import EVENT_SUFFIX, GRAPH_METADATA

SERVICE_TO_STAGE = {s.service: name for name, s in STAGES.items()}
REQUEST_SENT, REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = range(4)
MCAP_MAGIC = b"\x89MCAP0\r\n"   # every MCAP file starts with it (the MCAP specification)


@dataclass
class StageCall:
    """One request/reply exchange with a stage service, in the order the requests were made."""

    stage: str
    service: str
    request: Any = None
    response: Any = None
    stamp_ns: int = 0        # when the request was made (its event's stamp, from the caller's or server's clock)
    log_ns: int = 0          # when the recorder first heard of the call
    key: tuple = field(default=(), repr=False)


def check_recording(path: str | Path) -> None:
    """Raise, naming the fix, unless `path` is an MCAP file (a missing file named as such)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such recording")
    with open(path, "rb") as handle:
        magic = handle.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:   # the reader's EndOfFile / InvalidMagic said nothing of the fix
        raise PerchError(f"{path}: not an MCAP recording ({'empty' if path.stat().st_size == 0 else 'another format'}); "
                         "give the run.mcap that perch plan, perch demo or perch record wrote")


def recorded_namespace(path: str | Path) -> str:
    """The namespace the recording's topics live in ('' for the root namespace or an older file)."""
    return str(metadata(path).get(GRAPH_METADATA, {}).get("namespace", ""))


def iter_messages(path: str | Path, topics: list[str] | None = None) -> Iterator[tuple[str, Any, int]]:
    """(topic, deserialized message, log time ns) in log-time order.

    Topic names, given and yielded, are relative to the recorded graph's namespace (`/perch/...`
    whatever namespace the graph ran in). Messages come as the installed classes, also from a
    recording made with older definitions (read by its own schemas; fields added since keep their
    defaults).
    """
    from perch_common.mcap_read import iter_mcap

    namespace = recorded_namespace(path)
    wanted = None if topics is None else [namespace + t for t in topics]
    readers: dict[int, Any] = {}
    check_recording(path)
    # A recording cut short (its recorder killed) is read as far as it goes (perch_common.mcap_read).
    for schema, channel, message in iter_mcap(path, wanted):
        topic = channel.topic[len(namespace):] if channel.topic.startswith(namespace + "/") else channel.topic
        if schema.id not in readers:
            readers[schema.id] = message_reader(schema.name, schema.data.decode())
        yield topic, readers[schema.id](message.data), message.log_time


def stage_calls(path: str | Path) -> list[StageCall]:
    """Every stage service call found in the recording (client- or server-side events)."""
    topics = ["/" + service + EVENT_SUFFIX for service in SERVICE_TO_STAGE]
    calls: dict[tuple, StageCall] = {}
    request_stamps: dict[tuple, dict[int, int]] = {}
    for topic, event, stamp in iter_messages(path, topics):
        service = topic[1: -len(EVENT_SUFFIX)]
        info = event.info
        key = (service, bytes(bytearray(info.client_gid)), int(info.sequence_number))
        made_ns = time_ns(info.stamp)
        call = calls.setdefault(key, StageCall(SERVICE_TO_STAGE[service], service, stamp_ns=made_ns, log_ns=stamp,
                                               key=key))
        if info.event_type in (REQUEST_SENT, REQUEST_RECEIVED):
            if call.request is None and len(event.request):
                call.request = event.request[0]
            request_stamps.setdefault(key, {})[info.event_type] = made_ns
        if info.event_type in (RESPONSE_SENT, RESPONSE_RECEIVED) and len(event.response) and call.response is None:
            call.response = event.response[0]
    # The request's own stamp orders the calls, the caller's before the server's: the recorder hears
    # events of different topics in no set order (a large crop request can reach it after the small
    # segment request made after the crop's reply), so its log time does not.
    for key, stamps in request_stamps.items():
        calls[key].stamp_ns = stamps.get(REQUEST_SENT, stamps.get(REQUEST_RECEIVED))
    ordered = sorted(calls.values(), key=lambda c: (c.stamp_ns, c.log_ns))
    resolve_mesh_ids(ordered)
    return ordered


def resolve_mesh_ids(calls: list[StageCall]) -> None:
    """Give id-only meshes (perch_common.mesh_cache) the arrays recorded under that id earlier.

    Each mesh is recorded once, where it first travelled with its arrays; later requests and
    replies name it by content id. An id recorded nowhere with arrays stays id-only.
    """
    from perch_common.ros.conversions import is_id_only

    meshes: dict[str, Any] = {}
    for call in calls:
        for message in (call.request, call.response):
            mesh = getattr(message, "mesh", None)
            if mesh is None or not mesh.content_id:
                continue
            if is_id_only(mesh):
                if mesh.content_id in meshes:
                    message.mesh = meshes[mesh.content_id]
            else:
                meshes.setdefault(mesh.content_id, mesh)


def metadata(path: str | Path) -> dict[str, dict[str, Any]]:
    """Metadata records by name, JSON values decoded where they are JSON."""
    from perch_common.mcap_read import scan_mcap

    check_recording(path)
    out: dict[str, dict[str, Any]] = {}
    for name, record in scan_mcap(path).metadata.items():   # read also from a recording without summary
        values = {}
        for key, value in record.items():
            try:
                values[key] = json.loads(value)
            except ValueError:
                values[key] = value
        out[name] = values
    return out


def recorded_topics(path: str | Path) -> list[str]:
    """The topics of a recording, sorted: from its summary when it has one (no message is read), else
    from a scan of the whole file."""
    from mcap.reader import make_reader

    check_recording(path)
    try:
        with open(path, "rb") as handle:
            summary = make_reader(handle).get_summary()
    except Exception:   # noqa: BLE001 - a damaged summary: the scan below reads what there is
        summary = None
    if summary is not None and summary.channels:
        return sorted({channel.topic for channel in summary.channels.values()})
    return sorted(channel_counts(path))


def channel_counts(path: str | Path) -> dict[str, int]:
    """Messages per topic (those that could be read)."""
    from perch_common.mcap_read import scan_mcap

    check_recording(path)
    scan = scan_mcap(path)   # counted by reading, so a recording without summary is counted too
    return {scan.channels[cid].topic: n for cid, n in scan.counts.items() if cid in scan.channels}
