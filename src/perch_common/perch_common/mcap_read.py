"""Reading MCAP files that may be damaged: every chunk's CRC checked, a file cut short (a recorder
killed with SIGKILL leaves no summary) read up to the cut, and what was lost said in words.

`scan_mcap(path)` walks the file record by record (the mcap library's record parsers, our own walk,
so that a bad chunk is skipped rather than ending the read) and returns an McapScan: schemas,
channels, message counts per channel, metadata, and `problems` (chunk CRC mismatches, a truncated
last record, a missing summary). `iter_mcap(path, topics)` yields (schema, channel, message) of
an intact file through the library's indexed reader, and of a damaged one through the walk,
skipping the damaged chunks. Scans are kept per (path, size, mtime): a bag read three times (info,
intrinsics, frames) is walked once.
"""

from __future__ import annotations

import io
import mmap
import struct
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

MAGIC = b"\x89MCAP0\r\n"
# Opcodes (MCAP specification).
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
METADATA, DATA_END = 0x0C, 0x0F
_RECORD_HEAD = struct.Struct("<BQ")
MAX_RECORD = 4 * 2 ** 30   # as the mcap library's limit: a larger length is corruption, not data


class McapReadError(ValueError):
    """An MCAP that holds nothing readable, with the reason."""


@dataclass
class McapScan:
    """What a walk through an MCAP file found, damage included."""

    path: str
    size: int
    schemas: dict = field(default_factory=dict)          # id -> mcap Schema
    channels: dict = field(default_factory=dict)         # id -> mcap Channel
    counts: dict = field(default_factory=dict)           # channel id -> messages read
    metadata: dict = field(default_factory=dict)         # name -> dict
    start_ns: int = 0
    end_ns: int = 0
    has_summary: bool = False                            # the file ends with its footer (not cut short)
    bad_chunks: list = field(default_factory=list)       # (byte offset, first ns, last ns) of chunks failing CRC
    problems: list = field(default_factory=list)         # one sentence each
    read_bytes: int = 0                                  # bytes up to the last whole record

    @property
    def messages(self) -> int:
        """Messages that could be read."""
        return sum(self.counts.values())

    @property
    def intact(self) -> bool:
        """No damage found and the summary is there: the indexed reader may be used."""
        return self.has_summary and not self.problems

    def damage(self) -> str:
        """One line on what was lost ('' when nothing)."""
        if not self.problems:
            return ""
        return (f"{self.path}: " + "; ".join(self.problems) + f"; recovered {self.messages} message(s) "
                f"from {len(self.channels)} channel(s)")


_SCANS: dict[tuple, McapScan] = {}
_LOCK = threading.Lock()


def scan_mcap(path: str | Path) -> McapScan:
    """Walk `path` (cached per size and mtime); raises McapReadError when it is not an MCAP at all."""
    path = Path(path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    with _LOCK:
        if key in _SCANS:
            return _SCANS[key]
    scan = McapScan(str(path), stat.st_size)
    for _ in _walk(path, scan, keep=None):
        pass
    with _LOCK:
        if len(_SCANS) > 32:
            _SCANS.clear()
        _SCANS[key] = scan
    return scan


def iter_mcap(path: str | Path, topics: list[str] | None = None,
              log_time_order: bool = True) -> Iterator[tuple[object, object, object]]:
    """(schema, channel, message) of every readable message on `topics` (all when None).

    An intact file is read through the mcap library's indexed reader (CRCs validated, log-time
    order); a damaged one through the walk, in file order (log-time order within each chunk),
    its damaged chunks skipped: scan_mcap(path).damage() says what was lost.
    """
    scan = scan_mcap(path)
    if scan.intact:
        from mcap.reader import make_reader

        with open(path, "rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            yield from reader.iter_messages(topics=topics, log_time_order=log_time_order)
        return
    wanted = set() if topics is None else set(topics)   # empty: every topic
    if topics is not None and not wanted:
        return
    yield from _walk(Path(path), McapScan(str(path), scan.size), keep=wanted, ordered=log_time_order)


def _parse(opcode: int, body: bytes):
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Chunk, Message, Metadata, Schema

    stream = ReadDataStream(io.BytesIO(body))
    if opcode == SCHEMA:
        return Schema.read(stream)
    if opcode == CHANNEL:
        return Channel.read(stream)
    if opcode == MESSAGE:
        return Message.read(stream, len(body))
    if opcode == CHUNK:
        return Chunk.read(stream)
    if opcode == METADATA:
        return Metadata.read(stream)
    return None


def _walk(path: Path, scan: McapScan, keep: set | None, ordered: bool = False) -> Iterator[tuple]:
    """Fill `scan` record by record; yield (schema, channel, message) for channels on `keep`'s topics
    (nothing when keep is None: a scan only)."""
    from mcap.stream_reader import breakup_chunk

    with open(path, "rb") as handle:
        if scan.size < len(MAGIC) or handle.read(len(MAGIC)) != MAGIC:
            raise McapReadError(f"{path}: not an MCAP file (no MCAP magic at its start)")
        data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) if scan.size else b""
    try:
        position, size = len(MAGIC), scan.size

        def take(record) -> Iterator[tuple]:
            kind = type(record).__name__
            if kind == "Schema":
                scan.schemas[record.id] = record
            elif kind == "Channel":
                scan.channels[record.id] = record
            elif kind == "Message":
                channel = scan.channels.get(record.channel_id)
                scan.counts[record.channel_id] = scan.counts.get(record.channel_id, 0) + 1
                scan.start_ns = record.log_time if not scan.start_ns else min(scan.start_ns, record.log_time)
                scan.end_ns = max(scan.end_ns, record.log_time)
                if keep is not None and channel is not None and (not keep or channel.topic in keep):
                    yield scan.schemas.get(channel.schema_id), channel, record
            elif kind == "Metadata":
                scan.metadata[record.name] = dict(record.metadata)

        while position < size:
            if position + _RECORD_HEAD.size > size:
                scan.problems.append(f"the file is cut short, with no summary: it ends {size - position} byte(s) into "
                                     f"a record header at byte {position}")
                break
            opcode, length = _RECORD_HEAD.unpack_from(data, position)
            if length > MAX_RECORD or (opcode == 0 and length == 0):
                scan.problems.append(f"corrupt record header at byte {position} (opcode {opcode}, length {length}); "
                                     "nothing after it can be read")
                break
            end = position + _RECORD_HEAD.size + length
            if end > size:
                scan.problems.append(f"the file is cut short, with no summary: its last record (at byte {position}) "
                                     f"has {size - position - _RECORD_HEAD.size} of {length} bytes, its messages "
                                     "are lost")
                break
            if opcode in (DATA_END, FOOTER):
                # The data section ended properly; the summary is usable only with the footer and the
                # closing magic after it (a footer record is 20 bytes of body).
                footer_at = size - len(MAGIC) - _RECORD_HEAD.size - 20
                scan.has_summary = (size >= footer_at > 0 and bytes(data[size - len(MAGIC):]) == MAGIC
                                    and data[footer_at] == FOOTER)
                if not scan.has_summary:
                    scan.problems.append("the summary at the end of the file is cut short (every message is "
                                         "there; only the index is lost)")
                position = end
                break
            body = bytes(data[position + _RECORD_HEAD.size:end])
            try:
                record = _parse(opcode, body)
            except Exception as exc:  # the parsers raise several types for garbage
                scan.problems.append(f"unreadable record at byte {position} ({type(exc).__name__})")
                position = end
                continue
            if opcode == CHUNK:
                try:
                    inner = breakup_chunk(record, validate_crc=True)
                except Exception as exc:  # CRCValidationError, or a decompressor's error on corrupt bytes
                    scan.bad_chunks.append((position, record.message_start_time, record.message_end_time))
                    what = "fails its CRC check" if "CRC" in type(exc).__name__ else f"is corrupt ({type(exc).__name__})"
                    span = (record.message_end_time - record.message_start_time) / 1e9
                    scan.problems.append(f"chunk at byte {position} {what}: its messages ({span:.2f} s from "
                                         f"log time {record.message_start_time}) are lost")
                    position = end
                    continue
                if ordered:
                    # Channels and schemas first (they precede their messages), messages by log time.
                    inner = sorted(inner, key=lambda r: (type(r).__name__ == "Message", getattr(r, "log_time", 0)))
                for item in inner:
                    yield from take(item)
            elif record is not None:
                yield from take(record)
            position = end
        scan.read_bytes = position
        if not scan.has_summary and not any("cut short" in p or "corrupt record" in p for p in scan.problems):
            scan.problems.append("the recording has no summary (its writer was stopped before closing it)")
    finally:
        if isinstance(data, mmap.mmap):
            data.close()

