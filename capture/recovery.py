"""Reading MCAP files record by record up to where they stop, and rebuilding cut-off ones.

A recording cut off by a kill or a power loss is a valid MCAP prefix: magic, header,
metadata, attachments and complete chunks, then perhaps a half-written chunk or a tail of
zeros, and no summary. `scan` walks the records in file order and stops cleanly at the
first one that is incomplete or damaged (a chunk whose CRC or decompression fails).
`recover` writes what the scan found into a new, indexed file and merges the journal:
labels and operator markers missing from the file are added.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import breakup_chunk

from capture import topics as T
from capture.errors import CaptureError
from capture.journal import journal_path, read_journal

log = logging.getLogger(__name__)

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
RECORD_HEAD = struct.Struct("<BQ")  # opcode, length: before every record
_KNOWN_OPCODES = {int(op) for op in Opcode}
_RECORD_LIMIT = 1 << 31  # no walkcap record comes near 2 GiB: a bigger length is garbage


class NotMcapError(CaptureError):
    """The file is not an MCAP recording at all."""


@dataclass
class ScanResult:
    """How far a file could be read. Filled in while (and after) `scan` yields."""

    size: int = 0
    valid_end: int = 0  # offset just after the last complete data record
    complete: bool = False  # footer and closing magic found: the writer finished it
    reason: str = ""  # why the scan stopped before the end, if it did
    header: Header | None = None
    records: int = 0

    @property
    def lost_bytes(self) -> int:
        return max(0, self.size - self.valid_end) if not self.complete else 0


def check_magic(path: str | os.PathLike) -> None:
    """Raise NotMcapError unless the file starts like an MCAP file."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
    except IsADirectoryError:
        raise NotMcapError(f"{path} is a folder, not an MCAP recording") from None
    if head != MAGIC:
        what = "empty" if not head else "not an MCAP recording (no MCAP magic at its start)"
        raise NotMcapError(f"{path} is {what}")


def scan(stream: BinaryIO, result: ScanResult | None = None) -> Iterator[McapRecord]:
    """Records in file order (chunks opened into their schemas, channels and messages),
    up to the data end or the first incomplete or damaged record. Summary records are not
    yielded: everything they say is also in the data section."""
    result = result if result is not None else ScanResult()
    stream.seek(0, io.SEEK_END)
    result.size = stream.tell()
    stream.seek(0)
    if stream.read(len(MAGIC)) != MAGIC:
        raise NotMcapError("not an MCAP recording (no MCAP magic at its start)")
    offset = len(MAGIC)
    result.valid_end = offset
    while True:
        head = stream.read(RECORD_HEAD.size)
        if len(head) < RECORD_HEAD.size:
            result.reason = f"cut off at byte {offset}" if head else "ends without a footer"
            return
        opcode, length = RECORD_HEAD.unpack(head)
        if opcode not in _KNOWN_OPCODES and opcode < 0x80 or length > _RECORD_LIMIT:
            result.reason = f"unreadable data from byte {offset} (opcode {opcode:#x})"
            return
        body = stream.read(length)
        if len(body) < length:
            result.reason = f"cut off inside a record at byte {offset}"
            return
        try:
            records = _parse(opcode, body)
        except Exception as e:  # damaged: stop here, everything before is good
            result.reason = f"damaged record at byte {offset}: {e}"
            return
        offset += RECORD_HEAD.size + length
        if opcode == Opcode.FOOTER:
            result.complete = stream.read(len(MAGIC)) == MAGIC
            if not result.complete:
                result.reason = "footer without closing magic"
            return
        if opcode in (Opcode.DATA_END,):
            # the summary follows; its records repeat the data section: check the ending
            result.valid_end = offset
            stream.seek(-len(MAGIC), io.SEEK_END)
            result.complete = stream.read(len(MAGIC)) == MAGIC
            if not result.complete:
                result.reason = "cut off in the summary"
            return
        result.valid_end = offset
        for record in records:
            if isinstance(record, Header):
                result.header = record
            result.records += 1
            yield record


def _parse(opcode: int, body: bytes) -> list[McapRecord]:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(stream)
        return breakup_chunk(chunk, validate_crc=True)
    if opcode == Opcode.MESSAGE:
        return [Message.read(stream, len(body))]
    reader = {
        Opcode.HEADER: Header,
        Opcode.SCHEMA: Schema,
        Opcode.CHANNEL: Channel,
        Opcode.METADATA: Metadata,
        Opcode.ATTACHMENT: Attachment,
        Opcode.DATA_END: DataEnd,
        Opcode.FOOTER: Footer,
    }.get(opcode)
    if reader is None:
        return []  # indexes and statistics: rebuilt by whoever needs them
    record = reader.read(stream)
    if opcode == Opcode.ATTACHMENT:
        (crc,) = struct.unpack("<I", body[-4:])  # covers every field before it; 0 = none
        if crc and zlib.crc32(body[:-4]) != crc:
            raise ValueError("attachment CRC mismatch")
    return [record]


@dataclass
class RecoveryReport:
    source: str
    output: str
    complete: bool  # the source was already a finished file
    reason: str  # where and why the source stopped
    valid_bytes: int
    lost_bytes: int
    messages: int
    topics: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    labels_added: int = 0
    events_added: int = 0
    journal: str = ""

    @property
    def duration_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) * 1e-9


def default_output(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.with_name(p.stem + ".recovered" + p.suffix)


def recover(
    path: str | os.PathLike,
    output: str | os.PathLike | None = None,
    *,
    journal: str | os.PathLike | None = None,
    overwrite: bool = False,
) -> RecoveryReport:
    """Write every complete record of `path` into a new indexed MCAP file, with the labels
    and markers of the journal that the file lacks. The source is never modified."""
    from mcap.writer import CompressionType, Writer

    source = Path(path)
    check_magic(source)
    out = Path(output) if output is not None else default_output(source)
    if out.resolve() == source.resolve():
        raise CaptureError("the output must be a new file: the original is kept as it is")
    if out.exists() and not overwrite:
        raise CaptureError(f"{out} exists (choose another output, or remove it)")
    jpath = Path(journal) if journal is not None else journal_path(source)
    entries = read_journal(jpath)

    result = ScanResult()
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    topics_by_channel: dict[int, str] = {}
    counts: dict[str, int] = {}
    seen: dict[str, set] = {T.LABELS: set(), T.EVENTS: set()}
    first = last = None
    tmp = out.with_name(out.name + ".partial")
    with open(source, "rb") as f, open(tmp, "wb") as g:
        writer = Writer(g, chunk_size=4 * 1024 * 1024, compression=CompressionType.ZSTD)
        started = False
        for record in scan(f, result):
            if isinstance(record, Header):
                writer.start(profile=record.profile, library=record.library)
                started = True
                continue
            if not started:
                writer.start()
                started = True
            if isinstance(record, Schema):
                if record.id not in schema_ids:
                    schema_ids[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data
                    )
            elif isinstance(record, Channel):
                if record.id not in channel_ids:
                    channel_ids[record.id] = writer.register_channel(
                        record.topic,
                        record.message_encoding,
                        schema_ids.get(record.schema_id, 0),
                        record.metadata,
                    )
                    topics_by_channel[record.id] = record.topic
            elif isinstance(record, Message):
                channel = channel_ids.get(record.channel_id)
                if channel is None:
                    continue  # its channel record was lost: undecodable
                topic = topics_by_channel[record.channel_id]
                writer.add_message(
                    channel, record.log_time, record.data, record.publish_time, record.sequence
                )
                counts[topic] = counts.get(topic, 0) + 1
                if topic in seen:
                    seen[topic].add(_key(topic, record.data))
                if topic not in (T.LABELS, T.EVENTS):
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, record.metadata)
            elif isinstance(record, Attachment):
                writer.add_attachment(
                    record.create_time, record.log_time, record.name, record.media_type, record.data
                )
        if not started:
            writer.start()
        labels_added, events_added = _merge_journal(
            writer, entries, seen, topics_by_channel, channel_ids, counts
        )
        writer.add_metadata(
            "recovery",
            {
                "source": source.name,
                "source_bytes": str(result.size),
                "valid_bytes": str(result.valid_end),
                "source_complete": str(result.complete),
                "reason": result.reason,
                "journal": jpath.name if entries else "",
                "labels_added_from_journal": str(labels_added),
                "events_added_from_journal": str(events_added),
            },
        )
        _add_derivation(writer, source, result)
        writer.finish()
        g.flush()
        os.fsync(g.fileno())
    os.replace(tmp, out)
    return RecoveryReport(
        source=str(source),
        output=str(out),
        complete=result.complete,
        reason=result.reason,
        valid_bytes=result.valid_end,
        lost_bytes=result.lost_bytes,
        messages=sum(counts.values()),
        topics=counts,
        first_ns=first,
        last_ns=last,
        labels_added=labels_added,
        events_added=events_added,
        journal=str(jpath) if entries else "",
    )


def _key(topic: str, data: bytes | dict) -> tuple:
    import json

    m = json.loads(data) if isinstance(data, (bytes, bytearray)) else data
    if topic == T.LABELS:
        return (int(m.get("time_ns", 0)), m.get("mode", ""), m.get("source", ""))
    return (int(m.get("time_ns", 0)), m.get("device", ""), m.get("kind", ""), m.get("message", ""))


def _merge_journal(
    writer,
    entries: list[dict],
    seen: dict[str, set],
    topics_by_channel: dict[int, str],
    channel_ids: dict[int, int],
    counts: dict[str, int],
) -> tuple[int, int]:
    """Add the journal's labels and markers that the file does not have."""
    by_topic = {topics_by_channel[old]: new for old, new in channel_ids.items()}
    added = {T.LABELS: 0, T.EVENTS: 0}
    for entry in entries:
        kind = entry.get("type")
        if kind == "label":
            topic, message = (
                T.LABELS,
                T.label_json(
                    entry.get("time_ns", 0), entry.get("mode", ""), entry.get("source", "")
                ),
            )
        elif kind == "event":
            topic = T.EVENTS
            message = T.event_json({k: v for k, v in entry.items() if k != "type"})
        else:
            continue
        key = _key(topic, message)
        if key in seen[topic]:
            continue
        seen[topic].add(key)
        channel = by_topic.get(topic)
        if channel is None:
            spec = T.topic_spec(topic)
            schema = writer.register_schema(
                spec.schema_name, spec.schema_encoding, spec.schema_data
            )
            channel = writer.register_channel(
                topic, spec.message_encoding, schema, {"description": T.DESCRIPTIONS[topic]}
            )
            by_topic[topic] = channel
        t = message["time_ns"]
        writer.add_message(channel, t, T.encode_json(message), t, 0)
        counts[topic] = counts.get(topic, 0) + 1
        added[topic] += 1
    return added[T.LABELS], added[T.EVENTS]


def _add_derivation(writer, source: Path, result: ScanResult) -> None:
    """The recovered copy's own identity and lineage (capture.corpus)."""
    import uuid

    from capture.corpus import RECOVERED, derivation
    from capture.reader import open_recording

    try:
        original = open_recording(source)
    except CaptureError:
        return  # its metadata is unreadable: the "recovery" record names the source
    how = f"recovered: {result.valid_end} of {result.size} bytes readable"
    if result.reason:
        how += f" ({result.reason})"
    writer.add_metadata(
        "derivation",
        T.encode_metadata(derivation(original, str(uuid.uuid4()), RECOVERED, how)),
    )
