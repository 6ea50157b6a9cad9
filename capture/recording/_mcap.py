"""The low-level MCAP reading of walkcap recordings, record by record, up to where a file stops.

A recording cut off by a kill or a power loss is a valid MCAP prefix: magic, header,
metadata, attachments and complete chunks, then perhaps a half-written chunk or a tail of
zeros, and no summary. `scan` walks the records in file order, believing a record only
when its structure proves it (most bytes of a record's head and of the summary are covered
by no CRC, and one flipped bit there must not pass for a record), skipping and listing
damage up to the next record that proves itself, and stops at the end of what is readable.
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
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)

from capture.errors import CaptureError
from capture.recording.digests import located_damage
from devices import clock

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
    lost: bool = True  # False: bytes no reader needs (a record head its content proves)
    record: str = ""  # a record its digest does not prove ("metadata session"): kept as read

    def describe(self, origin_ns: int | None = None) -> str:
        if self.record:
            where = f" ({self.length} bytes at byte {self.offset})" if self.length else ""
            return f"{self.record}{where} {self.reason}"
        if not self.lost:
            return f"{self.length} bytes at byte {self.offset}, nothing lost: {self.reason}"
        where = f"{self.length} bytes at byte {self.offset}"
        if self.start_ns is not None and self.end_ns is not None:
            o = origin_ns if origin_ns is not None else self.start_ns
            where += (
                f", {clock.seconds(self.start_ns - o):.2f}-{clock.seconds(self.end_ns - o):.2f} s"
            )
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
    finished: bool = False  # footer and closing magic where the file ends: the writer closed it
    complete: bool = False  # finished and nothing damaged
    reason: str = ""  # why the scan stopped before the end, if it did
    header: Header | None = None
    records: int = 0
    damaged: list[Damage] = field(default_factory=list)  # found, with readable data after
    last_log_ns: int | None = None  # of the last message read
    record_at: tuple[int, int] = (0, 0)  # offset and length of the record being yielded
    record_raw: bytes | None = None  # its bytes, when it is a header or metadata record

    @property
    def lost_bytes(self) -> int:
        return max(0, self.size - self.valid_end) if not self.finished else 0

    @property
    def damaged_bytes(self) -> int:
        return sum(d.length for d in self.damaged if d.lost)

    @property
    def lost(self) -> list[Damage]:
        """The damaged regions whose records are skipped."""
        return [d for d in self.damaged if d.lost]


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


def file_bytes(stream: BinaryIO):
    """The whole file as a buffer: mapped when it is a file, read when it is not."""
    import mmap

    try:
        return mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        stream.seek(0)
        return stream.read()


_RELEASE_BYTES = 32 << 20


def _release(data, released: int, offset: int) -> int:
    """Give back the mapped pages before `offset`, every 32 MiB: a mapping's pages count
    as the process's memory until dropped; reading them again (a resync) maps them again."""
    if offset - released < _RELEASE_BYTES or not hasattr(data, "madvise"):
        return released
    import mmap

    cut = offset - offset % mmap.PAGESIZE
    try:
        data.madvise(mmap.MADV_DONTNEED, released, cut - released)
    except (OSError, ValueError, AttributeError):
        return offset  # nothing to give back on this system
    return cut


# A record head whose length is below 4 GiB: an opcode, four bytes, four zeros.
_CANDIDATE = re.compile(rb"(?=[\x01-\x0f][\x00-\xff]{4}\x00{4})", re.DOTALL)

_OPCODE_NAMES = {int(op): op.name.lower().replace("_", " ") for op in Opcode}
# What may follow the data end: the summary section and the footer.
_SUMMARY_OPCODES = {
    Opcode.SCHEMA,
    Opcode.CHANNEL,
    Opcode.CHUNK_INDEX,
    Opcode.ATTACHMENT_INDEX,
    Opcode.METADATA_INDEX,
    Opcode.STATISTICS,
    Opcode.SUMMARY_OFFSET,
    Opcode.FOOTER,
}
# What a walkcap data section holds (a record that may follow an uncheckable one).
_DATA_OPCODES = {
    Opcode.SCHEMA,
    Opcode.CHANNEL,
    Opcode.CHUNK,
    Opcode.MESSAGE_INDEX,
    Opcode.METADATA,
    Opcode.ATTACHMENT,
    Opcode.DATA_END,
    Opcode.FOOTER,
}
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_FIELDS = struct.Struct("<QQQI")  # start time, end time, uncompressed size and CRC
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_FOOTER_AT_END = RECORD_HEAD.size + 20 + len(MAGIC)  # footer record and closing magic


class _Unreadable(Exception):
    pass


@dataclass
class _Proven:
    """A record whose structure proves it: what it holds and where the next one starts."""

    opcode: int
    records: list
    end: int
    positions: dict | None = None  # a chunk's messages: offset inside it -> (channel, time)
    repaired: str = ""  # the head bytes that were wrong, when its content proved it anyway
    ending: str = ""  # data end and footer: "complete" or "cut" (cut off in the summary)
    start: int = 0  # where a record found by resynchronising starts


def _exact(cls, body) -> McapRecord:
    """A record read from exactly its body: a short or a long body is no such record."""
    stream = ReadDataStream(io.BytesIO(body))
    record = cls.read(stream, len(body)) if cls is Message else cls.read(stream)
    if stream.count != len(body):
        raise ValueError(f"{len(body)} bytes, the fields take {stream.count}")
    return record


def _decompress(compression: str, payload) -> bytes | None:
    if compression == "" and bytes(payload[:4]) != _ZSTD_MAGIC:
        return bytes(payload)
    if compression not in ("", "zstd") and bytes(payload[:4]) != _ZSTD_MAGIC:
        return None  # walkcap writes zstd; a damaged name is forgiven when the data is zstd
    import zstandard

    try:
        out = zstandard.ZstdDecompressor().decompressobj().decompress(bytes(payload))
    except zstandard.ZstdError:
        return None
    return out


def _chunk_records(raw: bytes):
    """(records, message positions) of a chunk's uncompressed records, None unless every
    record in it is a schema, a channel or a message that fills exactly its length."""
    records: list[McapRecord] = []
    positions: dict[int, tuple[int, int]] = {}
    at, end = 0, len(raw)
    kinds = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.MESSAGE: Message}
    try:
        while at < end:
            if end - at < RECORD_HEAD.size:
                return None
            opcode, length = RECORD_HEAD.unpack_from(raw, at)
            body_at = at + RECORD_HEAD.size
            if opcode not in kinds or body_at + length > end:
                return None
            if opcode == Opcode.MESSAGE:  # its data fills the rest: only the head can misfit
                if length < _MESSAGE_HEAD.size:
                    return None
                cid, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(raw, body_at)
                record = Message(
                    channel_id=cid,
                    sequence=sequence,
                    log_time=log_time,
                    publish_time=publish_time,
                    data=raw[body_at + _MESSAGE_HEAD.size : body_at + length],
                )
                positions[at] = (cid, log_time)
            else:
                record = _exact(kinds[opcode], raw[body_at : body_at + length])
            records.append(record)
            at = body_at + length
    except Exception:  # the library's errors for fields that do not fit
        return None
    return records, positions


def _chunk(data, body_at: int, head_length: int | None) -> _Proven | None:
    """The chunk whose fields start at body_at, proven by its CRC (by its structure alone
    when it has none and its head agrees); None when nothing proves it. Its extent comes
    from its own fields, or from the head's length when those fields are the damaged ones."""
    size = len(data)
    if body_at + 32 > size:
        return None
    _, _, uncompressed_size, crc = _CHUNK_FIELDS.unpack_from(data, body_at)
    (name_length,) = struct.unpack_from("<I", data, body_at + 28)
    at = body_at + 32 + name_length
    if name_length > 16 or at + 8 > size:
        return None
    try:
        compression = bytes(data[body_at + 32 : at]).decode()
    except UnicodeDecodeError:
        compression = "?"
    (records_length,) = struct.unpack_from("<Q", data, at)
    at += 8
    lengths = [records_length]
    if head_length is not None:
        lengths.append(head_length - (at - body_at))
    for n in dict.fromkeys(lengths):
        if n < 0 or at + n > size:
            continue
        consistent = n == records_length and (
            head_length is None or at + n == body_at + head_length
        )
        if not crc and not consistent:
            continue  # without a CRC only fields that agree vouch for it
        raw = _decompress(compression, data[at : at + n])
        if raw is None or (crc and zlib.crc32(raw) != crc):
            continue
        inner = _chunk_records(raw)
        if inner is None:
            continue
        repaired = "" if consistent and len(raw) == uncompressed_size else "length"
        return _Proven(Opcode.CHUNK, inner[0], at + n, inner[1], repaired)
    return None


def _message_index(data, body_at: int, positions: dict | None, exact_end: int | None) -> int:
    """The end of the message index at body_at if every entry names a message of the chunk
    before it (channel and log time at that offset); raises ValueError otherwise."""
    if positions is None:
        raise ValueError("no chunk before it")
    if body_at + 6 > len(data):
        raise ValueError("cut off")
    channel, length = struct.unpack_from("<HI", data, body_at)
    end = body_at + 6 + length
    if length % 16 or end > len(data) or (exact_end is not None and end != exact_end):
        raise ValueError("its length does not fit its entries")
    if exact_end is None and not length:
        raise ValueError("empty")
    for k in range(length // 16):
        log_time, offset = struct.unpack_from("<QQ", data, body_at + 6 + 16 * k)
        if positions.get(offset) != (channel, log_time):
            raise ValueError("an entry names no message of the chunk before it")
    return end


def _ending(data, at: int) -> str:
    """How the file goes on after a data end at `at`: "complete" (the footer and closing
    magic end the file, the footer's summary starting here), "cut" (summary records up to
    a cut or a zero-filled tail); "" when anything else follows: then it is no data end."""
    size = len(data)
    footer = size - _FOOTER_AT_END
    if footer >= at and data[size - len(MAGIC) :] == MAGIC:
        opcode, length = RECORD_HEAD.unpack_from(data, footer)
        (summary_start,) = struct.unpack_from("<Q", data, footer + RECORD_HEAD.size)
        if opcode == Opcode.FOOTER and length == 20:
            if summary_start == at or (summary_start == 0 and footer == at):
                return "complete"
    while at + RECORD_HEAD.size <= size:
        opcode, length = RECORD_HEAD.unpack_from(data, at)
        if opcode == 0 and _zeros_to_end(data, at):
            return "cut"
        if opcode not in _SUMMARY_OPCODES or opcode == Opcode.FOOTER:
            return ""
        at += RECORD_HEAD.size + length
    return "cut"


def _plausible_next(data, at: int) -> bool:
    """After a record nothing checks: the next record looks like one, or the file ends
    (cut, or a zero-filled tail)."""
    size = len(data)
    if size - at < RECORD_HEAD.size:
        return True
    opcode, length = RECORD_HEAD.unpack_from(data, at)
    if opcode in _DATA_OPCODES and length <= _RECORD_LIMIT:
        return True
    return opcode == 0 and _zeros_to_end(data, at)


_NONZERO = re.compile(rb"[^\x00]")


def _zeros_to_end(data, at: int) -> bool:
    """Only zeros from `at` on: what a file system leaves after a power loss."""
    return _NONZERO.search(data, at) is None


def _attachment_end(data, body_at: int) -> int:
    """The end of the attachment at body_at by its own fields; ValueError if they overrun."""
    at = body_at + 16
    for _ in range(2):
        (n,) = struct.unpack_from("<I", data, at)
        at += 4 + n
    (n,) = struct.unpack_from("<Q", data, at)
    end = at + 8 + n + 4
    if end > len(data):
        raise ValueError("runs past the end of the file")
    return end


def _check_attachment(data, body_at: int, end: int, need_crc: bool) -> list:
    record = _exact(Attachment, data[body_at:end])
    (crc,) = struct.unpack_from("<I", data, end - 4)  # covers every field before it; 0 = none
    if crc and zlib.crc32(data[body_at : end - 4]) != crc:
        raise ValueError("attachment CRC mismatch")
    if not crc and (need_crc or not _plausible_next(data, end)):
        raise ValueError("no CRC to prove it")
    return [record]


def _metadata_end(data, body_at: int) -> int:
    (n,) = struct.unpack_from("<I", data, body_at)
    if not n:
        raise ValueError("no name")  # walkcap names every metadata record
    at = body_at + 4 + n
    (m,) = struct.unpack_from("<I", data, at)
    end = at + 4 + m
    if end > len(data):
        raise ValueError("runs past the end of the file")
    return end


def _prove(data, at: int, positions: dict | None, resync: bool = False) -> _Proven:
    """The record at `at` if its structure proves it, else _Unreadable naming it. A chunk
    and an attachment prove themselves by their CRC, a message index by pointing at the
    messages of the chunk before it, a data end and a footer by standing where the file
    ends; a header only at the start, and a metadata record (nothing checks its bytes) only
    when its fields fill it exactly and a record follows. `resync`: only records that can
    be believed without the record before them (no header, index or top-level message)."""
    size = len(data)
    if size - at < RECORD_HEAD.size:
        raise _Unreadable(f"cut off at byte {at}" if size > at else "ends without a footer")
    opcode, length = RECORD_HEAD.unpack_from(data, at)
    body_at = at + RECORD_HEAD.size
    end = body_at + length
    if opcode not in _DATA_OPCODES and opcode != Opcode.HEADER or length > _RECORD_LIMIT:
        what = f"opcode {opcode:#x}" + (" in the data section" if opcode in _KNOWN_OPCODES else "")
        raise _Unreadable(f"unreadable data from byte {at} ({what})")
    if end > size:
        raise _Unreadable(f"cut off inside a record at byte {at}")
    what = _OPCODE_NAMES.get(opcode, "record")
    try:
        if opcode == Opcode.CHUNK:
            proven = _chunk(data, body_at, length)
            if proven is None or (resync and proven.repaired):
                raise ValueError("CRC mismatch or broken structure")
            return proven
        if opcode == Opcode.ATTACHMENT:
            return _Proven(opcode, _check_attachment(data, body_at, end, resync), end)
        if opcode == Opcode.DATA_END or opcode == Opcode.FOOTER:
            if length != (4 if opcode == Opcode.DATA_END else 20):
                raise ValueError(f"length {length}")
            if opcode == Opcode.FOOTER:
                ending = "complete" if end == size - len(MAGIC) and data[end:] == MAGIC else ""
            else:
                ending = _ending(data, end)
            if not ending:
                raise ValueError("not where the file ends")
            return _Proven(opcode, [], end, ending=ending)
        if resync and opcode != Opcode.METADATA:
            raise ValueError("nothing to check it by")
        if opcode == Opcode.MESSAGE_INDEX:
            return _Proven(opcode, [], _message_index(data, body_at, positions, end), positions)
        if opcode == Opcode.HEADER and at != len(MAGIC):
            raise ValueError("a header after the start")
        cls = {
            Opcode.HEADER: Header,
            Opcode.SCHEMA: Schema,
            Opcode.CHANNEL: Channel,
            Opcode.METADATA: Metadata,
        }[opcode]
        record = _exact(cls, data[body_at:end])
        if isinstance(record, Metadata) and not record.name:
            raise ValueError("no name")  # walkcap names every metadata record: zeros
        if not _plausible_next(data, end):
            raise ValueError("no record follows it")
        return _Proven(opcode, [record], end)
    except _Unreadable:
        raise
    except Exception as e:  # the libraries' own errors for damaged bytes
        why = "CRC mismatch" if "crc" in str(e).lower() else (str(e) or type(e).__name__)
        raise _Unreadable(f"damaged {what} at byte {at}: {why}") from None


def _by_content(data, at: int, positions: dict | None) -> _Proven | None:
    """A record whose head (type byte or length) is damaged but whose own fields prove
    what it is: a chunk by its CRC, a message index by the chunk before it, an attachment
    by its CRC, the header at the start, metadata, a data end or a footer where the file
    ends. None when nothing proves anything here."""
    size = len(data)
    body_at = at + RECORD_HEAD.size
    if body_at > size:
        return None
    head_length = None
    if size - at >= RECORD_HEAD.size:
        (length,) = struct.unpack_from("<Q", data, at + 1)
        head_length = length if length <= _RECORD_LIMIT else None
    proven = _chunk(data, body_at, head_length)
    if proven is not None:
        return proven
    attempts = (
        (Opcode.MESSAGE_INDEX, lambda: _message_index(data, body_at, positions, None)),
        (Opcode.ATTACHMENT, lambda: _attachment_end(data, body_at)),
        (Opcode.METADATA, lambda: _metadata_end(data, body_at)),
        (Opcode.HEADER, lambda: _metadata_end(data, body_at) if at == len(MAGIC) else -1),
        (Opcode.DATA_END, lambda: body_at + 4),
        (Opcode.FOOTER, lambda: body_at + 20),
    )
    for opcode, extent in attempts:
        try:
            end = extent()
            if end < 0 or end > size:
                continue
            records: list = []
            ending = ""
            if opcode == Opcode.ATTACHMENT:
                records = _check_attachment(data, body_at, end, True)
            elif opcode in (Opcode.METADATA, Opcode.HEADER):
                records = [
                    _exact(Metadata if opcode == Opcode.METADATA else Header, data[body_at:end])
                ]
                if not _plausible_next(data, end):
                    continue
            elif opcode == Opcode.DATA_END:
                ending = _ending(data, end)
                if not ending:
                    continue
            elif opcode == Opcode.FOOTER:
                if end != size - len(MAGIC) or data[end:] != MAGIC:
                    continue
                ending = "complete"
        except Exception:  # fields that do not fit: not this kind of record
            continue
        return _Proven(opcode, records, end, positions, "type or length", ending)
    return None


def _resync(data, start: int) -> _Proven | None:
    """The next record after damage that proves itself without the records before it: a
    chunk or an attachment whose CRC matches, metadata followed by a record, a data end or
    a footer where the file ends."""
    for m in _CANDIDATE.finditer(data, start):
        at = m.start()
        try:
            proven = _prove(data, at, None, resync=True)
        except _Unreadable:
            continue
        proven.start = at
        return proven
    return None


def summary_damage(data) -> str:
    """Why the summary section of a finished file cannot be believed ("" when its CRC
    matches, or when it has none to check): then the data section is read instead."""
    size = len(data)
    footer = size - _FOOTER_AT_END
    if footer < len(MAGIC) or data[size - len(MAGIC) :] != MAGIC:
        return ""
    opcode, length = RECORD_HEAD.unpack_from(data, footer)
    if opcode != Opcode.FOOTER or length != 20:
        return "the footer is damaged"
    summary_start, _, crc = struct.unpack_from("<QQI", data, footer + RECORD_HEAD.size)
    if not crc:
        return ""
    if summary_start > footer or (summary_start and summary_start < len(MAGIC)):
        return "the footer is damaged (summary start)"
    first = summary_start or footer
    if zlib.crc32(data[first : size - len(MAGIC) - 4]) != crc:
        return "summary CRC mismatch"
    return ""


def scan(stream: BinaryIO, result: ScanResult | None = None) -> Iterator[McapRecord]:
    """`_scan`, and once every record is read, the header, metadata, schema and channel
    records checked against their digests (capture.recording.digests): each that fails is
    listed in `result.damaged` by name."""
    result = result if result is not None else ScanResult()
    checked: list[tuple] = []  # (record, offset, length, its bytes when top-level)
    for record in _scan(stream, result):
        if isinstance(record, (Header, Metadata, Schema, Channel)):
            checked.append((record, *result.record_at, result.record_raw))
        yield record
    result.damaged.extend(digest_damage(checked, finished=result.finished))
    result.complete = result.complete and not result.damaged


def digest_damage(checked: list[tuple], *, finished: bool) -> list[Damage]:
    """Damage for each (record, offset, length, bytes or None) its digest does not prove."""
    return [
        Damage(p.offset, p.length, p.why, lost=False, record=p.key)
        for p in located_damage(checked, finished=finished)
    ]


def _scan(stream: BinaryIO, result: ScanResult) -> Iterator[McapRecord]:
    """Records in file order (chunks opened into their schemas, channels and messages),
    up to the data end. Only records that their structure proves are believed (`_prove`);
    a record that proves nothing is damage, skipped up to the next record that proves
    itself and listed in `result.damaged` at its own offset; damage with nothing provable
    after it is where the file stops. A record whose head is damaged but whose content
    proves it (a chunk's CRC) is kept, and listed too. Summary records are not yielded:
    everything they say is also in the data section; a summary whose CRC fails is listed."""
    data = file_bytes(stream)
    result.size = len(data)
    if data[: len(MAGIC)] != MAGIC:
        raise NotMcapError("not an MCAP recording (no MCAP magic at its start)")
    offset = len(MAGIC)
    result.valid_end = offset
    released = 0  # the mapped bytes before this are given back
    damage_at: tuple[int, str] | None = None
    positions: dict | None = None  # the last chunk's messages, for its message indexes
    pending: _Proven | None = None
    while True:
        if pending is not None:
            proven, pending = pending, None
        else:
            try:
                proven = _prove(data, offset, positions)
            except _Unreadable as e:
                proven = _by_content(data, offset, positions)
                if proven is None:
                    if damage_at is None:
                        damage_at = (offset, str(e))
                    positions = None
                    pending = _resync(data, offset + 1)
                    if pending is None:  # nothing provable after it: the file stops here
                        result.reason = damage_at[1]
                        return
                    offset = pending.start
                    continue
                what = _OPCODE_NAMES.get(proven.opcode, "record")
                result.damaged.append(
                    Damage(
                        offset,
                        RECORD_HEAD.size,
                        f"{what} head damaged ({e}); its content proves it and is kept",
                        lost=False,
                    )
                )
        if proven.repaired and proven.opcode == Opcode.CHUNK and damage_at is None:
            if not result.damaged or result.damaged[-1].offset != offset:
                result.damaged.append(
                    Damage(
                        offset,
                        RECORD_HEAD.size,
                        "chunk length fields damaged; its CRC proves its content, kept",
                        lost=False,
                    )
                )
        if damage_at is not None:
            result.damaged.append(
                Damage(damage_at[0], offset - damage_at[0], damage_at[1], result.last_log_ns)
            )
            damage_at = None
        indexed = proven.opcode in (Opcode.CHUNK, Opcode.MESSAGE_INDEX)
        positions = proven.positions if indexed else None
        end = proven.end
        if proven.ending:
            result.valid_end = end if proven.opcode == Opcode.DATA_END else offset
            result.finished = proven.ending == "complete"
            if not result.finished:
                result.reason = "cut off in the summary"
            else:
                why = summary_damage(data)
                if why:
                    (start,) = struct.unpack_from(
                        "<Q", data, len(data) - _FOOTER_AT_END + RECORD_HEAD.size
                    )
                    start = min(start or end, len(data))
                    result.damaged.append(
                        Damage(
                            start,
                            len(data) - start,
                            f"{why}: its index is not believed, the data section is read",
                            lost=False,
                        )
                    )
            result.complete = result.finished and not result.damaged
            return
        result.record_at = (offset, end - offset)  # of what is yielded next: a chunk's own
        top = proven.opcode in (Opcode.HEADER, Opcode.METADATA)
        result.record_raw = bytes(data[offset:end]) if top else None
        offset = end
        result.valid_end = offset
        released = _release(data, released, offset)
        for record in proven.records:
            if isinstance(record, Header):
                result.header = record
            elif isinstance(record, Message):
                if result.damaged and result.damaged[-1].end_ns is None:
                    result.damaged[-1].end_ns = record.log_time
                result.last_log_ns = record.log_time
            result.records += 1
            yield record
