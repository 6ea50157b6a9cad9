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
import re
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
from devices.files import check_replaceable

log = logging.getLogger(__name__)

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
RECORD_HEAD = struct.Struct("<BQ")  # opcode, length: before every record
_KNOWN_OPCODES = {int(op) for op in Opcode}
_RECORD_LIMIT = 1 << 31  # no walkcap record comes near 2 GiB: a bigger length is garbage


class NotMcapError(CaptureError):
    """The file is not an MCAP recording at all."""


@dataclass
class Damage:
    """Bytes skipped between two readable records: what a flipped bit or a bad copy costs."""

    offset: int
    length: int
    reason: str
    start_ns: int | None = None  # the log times between which messages may be missing
    end_ns: int | None = None
    topics: tuple[str, ...] = ()  # topics of the chunks lost, when the file's index says

    def describe(self, origin_ns: int | None = None) -> str:
        where = f"{self.length} bytes at byte {self.offset}"
        if self.start_ns is not None and self.end_ns is not None:
            o = origin_ns if origin_ns is not None else self.start_ns
            where += f", {(self.start_ns - o) * 1e-9:.2f}-{(self.end_ns - o) * 1e-9:.2f} s"
        if self.topics:
            shown = ", ".join(self.topics[:4])
            more = f" and {len(self.topics) - 4} more" if len(self.topics) > 4 else ""
            where += f" ({shown}{more})"
        return f"{where}: {self.reason}"


@dataclass
class ScanResult:
    """How far a file could be read. Filled in while (and after) `scan` yields."""

    size: int = 0
    valid_end: int = 0  # offset just after the last complete data record
    complete: bool = False  # footer and closing magic found: the writer finished it
    reason: str = ""  # why the scan stopped before the end, if it did
    header: Header | None = None
    records: int = 0
    damaged: list[Damage] = field(default_factory=list)  # skipped, with readable data after
    last_log_ns: int | None = None  # of the last message read

    @property
    def lost_bytes(self) -> int:
        return max(0, self.size - self.valid_end) if not self.complete else 0

    @property
    def damaged_bytes(self) -> int:
        return sum(d.length for d in self.damaged)


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


def _file_bytes(stream: BinaryIO):
    """The whole file as a buffer: mapped when it is a file, read when it is not."""
    import mmap

    try:
        return mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        stream.seek(0)
        return stream.read()


# A record head whose length is below 4 GiB: an opcode, four bytes, four zeros.
_CANDIDATE = re.compile(rb"(?=[\x01-\x0f][\x00-\xff]{4}\x00{4})", re.DOTALL)


def _read_record(data, offset: int):
    """(opcode, records, next offset) of the record at offset; raises _Unreadable."""
    size = len(data)
    if size - offset < RECORD_HEAD.size:
        raise _Unreadable(f"cut off at byte {offset}" if size > offset else "ends without a footer")
    opcode, length = RECORD_HEAD.unpack_from(data, offset)
    if opcode not in _KNOWN_OPCODES and opcode < 0x80 or length > _RECORD_LIMIT:
        raise _Unreadable(f"unreadable data from byte {offset} (opcode {opcode:#x})")
    end = offset + RECORD_HEAD.size + length
    if end > size:
        raise _Unreadable(f"cut off inside a record at byte {offset}")
    try:
        records = _parse(opcode, bytes(data[offset + RECORD_HEAD.size : end]))
    except Exception as e:  # the libraries' own errors for damaged bytes
        what = _OPCODE_NAMES.get(opcode, "record")
        why = "CRC mismatch" if "crc" in str(e).lower() else (str(e) or type(e).__name__)
        raise _Unreadable(f"damaged {what} at byte {offset}: {why}") from None
    return opcode, records, end


_OPCODE_NAMES = {int(op): op.name.lower().replace("_", " ") for op in Opcode}


class _Unreadable(Exception):
    pass


def _plausible_head(data, offset: int) -> bool:
    if offset == len(data) - len(MAGIC):
        return data[offset:] == MAGIC
    if len(data) - offset < RECORD_HEAD.size:
        return False
    opcode, length = RECORD_HEAD.unpack_from(data, offset)
    return opcode in _KNOWN_OPCODES and offset + RECORD_HEAD.size + length <= len(data)


def _resync(data, start: int) -> int | None:
    """The offset of the next record after damage that can be trusted: a chunk or an
    attachment whose CRC matches, or a record that parses and is followed by another."""
    for m in _CANDIDATE.finditer(data, start):
        at = m.start()
        opcode, length = RECORD_HEAD.unpack_from(data, at)
        end = at + RECORD_HEAD.size + length
        if opcode not in _KNOWN_OPCODES or end > len(data):
            continue
        if opcode == Opcode.MESSAGE_INDEX or opcode == Opcode.HEADER:
            continue  # nothing to check them by; the chunk after them is found instead
        if opcode == Opcode.CHUNK and not _chunk_has_crc(data, at):
            continue
        try:
            _read_record(data, at)
        except _Unreadable:
            continue
        if opcode in (Opcode.CHUNK, Opcode.ATTACHMENT) or _plausible_head(data, end):
            return at
    return None


def _chunk_has_crc(data, at: int) -> bool:
    # Chunk: start time u64, end time u64, uncompressed size u64, uncompressed CRC u32.
    if at + RECORD_HEAD.size + 28 > len(data):
        return False
    (crc,) = struct.unpack_from("<I", data, at + RECORD_HEAD.size + 24)
    return crc != 0


def scan(stream: BinaryIO, result: ScanResult | None = None) -> Iterator[McapRecord]:
    """Records in file order (chunks opened into their schemas, channels and messages),
    up to the data end. A damaged record (a chunk whose CRC or decompression fails, bytes
    that are no record) is skipped up to the next record that can be trusted, and listed in
    `result.damaged`; damage with nothing readable after it is where the file stops.
    Summary records are not yielded: everything they say is also in the data section."""
    result = result if result is not None else ScanResult()
    data = _file_bytes(stream)
    result.size = len(data)
    if data[: len(MAGIC)] != MAGIC:
        raise NotMcapError("not an MCAP recording (no MCAP magic at its start)")
    offset = len(MAGIC)
    result.valid_end = offset
    damage_at: tuple[int, str] | None = None
    while True:
        try:
            opcode, records, end = _read_record(data, offset)
        except _Unreadable as e:
            if damage_at is None:
                damage_at = (offset, str(e))
            nxt = _resync(data, offset + 1)
            if nxt is None:  # nothing readable after it: the file stops here
                result.reason = damage_at[1]
                return
            offset = nxt
            continue
        if damage_at is not None:
            result.damaged.append(
                Damage(damage_at[0], offset - damage_at[0], damage_at[1], result.last_log_ns)
            )
            damage_at = None
        if opcode == Opcode.FOOTER:
            result.complete = data[end : end + len(MAGIC)] == MAGIC
            if not result.complete:
                result.reason = "footer without closing magic"
            return
        if opcode == Opcode.DATA_END:
            # the summary follows; its records repeat the data section: check the ending
            result.valid_end = end
            result.complete = data[-len(MAGIC) :] == MAGIC
            if not result.complete:
                result.reason = "cut off in the summary"
            return
        offset = end
        result.valid_end = offset
        for record in records:
            if isinstance(record, Header):
                result.header = record
            elif isinstance(record, Message):
                if result.damaged and result.damaged[-1].end_ns is None:
                    result.damaged[-1].end_ns = record.log_time
                result.last_log_ns = record.log_time
            result.records += 1
            yield record


def summary_of(stream: BinaryIO):
    """The file's summary (schemas, channels, chunk indexes), None if it has none readable."""
    from mcap.reader import make_reader

    try:
        stream.seek(0)
        return make_reader(stream).get_summary()
    except Exception:  # no footer or a damaged summary: the data section is all there is
        return None


def describe_damage(damage: list[Damage], summary) -> None:
    """Fill in the time span and topics of damaged regions from the file's chunk index."""
    if summary is None:
        return
    for d in damage:
        lost = [
            c
            for c in summary.chunk_indexes
            if c.chunk_start_offset < d.offset + d.length
            and c.chunk_start_offset + c.chunk_length > d.offset
        ]
        if not lost:
            continue
        d.start_ns = min(c.message_start_time for c in lost)
        d.end_ns = max(c.message_end_time for c in lost)
        d.topics = tuple(
            sorted(
                {
                    summary.channels[cid].topic
                    for c in lost
                    for cid in c.message_index_offsets
                    if cid in summary.channels
                }
            )
        )


def check(path: str | os.PathLike) -> ScanResult:
    """Read every record of a file, checking every chunk's CRC: what is damaged, where."""
    check_magic(path)
    result = ScanResult()
    with open(path, "rb") as f:
        for _ in scan(f, result):
            pass
        if result.damaged:
            describe_damage(result.damaged, summary_of(f))
    return result


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
    damaged: list[Damage] = field(default_factory=list)  # skipped inside the file
    unknown_channel_messages: int = 0  # messages whose channel record was in damaged bytes

    @property
    def salvaged(self) -> bool:
        return self.messages > 0

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
    if output is not None and not os.fspath(output):
        raise CaptureError("the output path is empty: name the file to write")
    out = Path(output) if output is not None else default_output(source)
    check_replaceable(out)
    if out.resolve() == source.resolve():
        raise CaptureError("the output must be a new file: the original is kept as it is")
    if out.exists() and not overwrite:
        raise CaptureError(f"{out} exists (choose another output, or remove it)")
    if journal is not None and not Path(journal).is_file():
        raise CaptureError(f"{journal}: no such journal (its labels would be missing)")
    jpath = Path(journal) if journal is not None else journal_path(source)
    entries = read_journal(jpath)

    result = ScanResult()
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    topics_by_channel: dict[int, str] = {}
    counts: dict[str, int] = {}
    seen: dict[str, set] = {T.LABELS: set(), T.EVENTS: set()}
    first = last = None
    unknown_channel = 0
    tmp = out.with_name(out.name + ".partial")
    with open(source, "rb") as f, open(tmp, "wb") as g:
        # A damaged chunk can hold the schema and channel records of later chunks: a
        # finished file's summary repeats them.
        summary = summary_of(f)
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
                if channel is None and summary is not None:
                    channel = _register_from_summary(
                        writer, summary, record.channel_id, schema_ids, channel_ids
                    )
                    if channel is not None:
                        topics_by_channel[record.channel_id] = summary.channels[
                            record.channel_id
                        ].topic
                if channel is None:
                    unknown_channel += 1  # its channel record was lost: undecodable
                    continue
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
        if result.records == 0 and not entries:
            g.close()
            tmp.unlink()
            raise CaptureError(
                f"{source}: nothing to recover ({result.reason or 'no readable record'})"
            )
        describe_damage(result.damaged, summary)
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
                "damaged_bytes": str(result.damaged_bytes),
                "damaged": "; ".join(d.describe() for d in result.damaged),
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
        damaged=result.damaged,
        unknown_channel_messages=unknown_channel,
    )


def _register_from_summary(writer, summary, channel_id, schema_ids, channel_ids):
    channel = summary.channels.get(channel_id)
    if channel is None:
        return None
    schema = summary.schemas.get(channel.schema_id)
    if schema is not None and schema.id not in schema_ids:
        schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
    channel_ids[channel_id] = writer.register_channel(
        channel.topic,
        channel.message_encoding,
        schema_ids.get(channel.schema_id, 0),
        channel.metadata,
    )
    return channel_ids[channel_id]


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
