"""A recording's messages as stored, in file order, finished file or not, and their decoders.

A finished file is read through its index, chunk by chunk; an unfinished one (a crash, a
full disk) record by record up to where it stops (capture.recording._mcap.scan). Damage
surfaces as one CaptureError line that names where and points at `walkcap recover`.
"""

from __future__ import annotations

import contextlib
import io
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from capture.errors import CaptureError
from capture.recording._mcap import RECORD_HEAD, Damage, ScanResult, scan


@contextlib.contextmanager
def damage_is_an_error(path: Path):
    """Bytes damaged inside a finished file (a bad disk, a bad copy) surface from the mcap,
    zstd and protobuf libraries as their own exceptions: one clear error instead."""
    try:
        yield
    except CaptureError:
        raise
    except Exception as e:
        raise CaptureError(
            f"{path}: the file is damaged ({type(e).__name__}: {e}); "
            "copy what is readable with `walkcap recover`"
        ) from None


def _damage_line(path: Path, what: str) -> str:
    return f"{path}: damaged, {what}; copy what is intact with `walkcap recover`"


class Decoders:
    """Decoders built from the schemas in the file: protobuf descriptors, JSON."""

    def __init__(self) -> None:
        from mcap_protobuf.decoder import DecoderFactory

        self._protobuf = DecoderFactory()
        self._by_channel: dict[int, Any] = {}

    def decode(self, schema, channel, data: bytes) -> Any:
        decoder = self._by_channel.get(channel.id)
        if decoder is None:
            if channel.message_encoding == "json":
                decoder = orjson.loads
            else:
                decoder = self._protobuf.decoder_for(channel.message_encoding, schema)
                if decoder is None:
                    raise CaptureError(
                        f"{channel.topic}: cannot decode {channel.message_encoding} "
                        f"messages with schema {schema.name if schema else None}"
                    )
            self._by_channel[channel.id] = decoder
        return decoder(data)


def iter_raw(
    path: Path,
    complete: bool,
    topics: set[str] | None,
    *,
    start: int | None = None,
    end: int | None = None,
    summary=None,
):
    """(schema, channel, message) in file order; with `start` / `end`, only the messages
    logged in [start, end) (ns, session clock). A finished file is read through its index
    (`summary`: the one already read, else read here): only the chunks that hold a wanted
    topic in that window are read. An unfinished one is read record by record."""
    from mcap.records import Channel, Message, Schema

    with open(path, "rb") as f:
        if complete:
            yield from iter_indexed(f, topics, start, end, summary)
            return
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        result = ScanResult()
        origin = None
        for record in scan(f, result):
            if result.lost:  # every reader stops at damage, with the same line
                raise CaptureError(_damage_line(path, result.lost[0].describe(origin)))
            if isinstance(record, Message) and origin is None:
                origin = record.log_time
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                if not _in_window(record.log_time, start, end):
                    continue
                yield schemas.get(channel.schema_id), channel, record


def _in_window(t: int, start: int | None, end: int | None) -> bool:
    return (start is None or t >= start) and (end is None or t < end)


def read_summary(f):
    """A finished file's summary (channels, schemas, statistics, chunk index)."""
    from mcap.reader import make_reader

    return make_reader(f).get_summary()


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def iter_indexed(f, topics: set[str] | None, start=None, end=None, summary=None):
    """A finished file's messages chunk by chunk, in file order, through its index:
    chunks without a wanted channel, or outside [start, end), are not read, and one chunk
    is in memory at a time (the mcap library's file-order iteration opens every chunk
    before the first message: a whole long recording in memory, and a wait before
    anything comes)."""
    from mcap.records import Message

    summary = summary if summary is not None else read_summary(f)
    wanted = {cid for cid, c in summary.channels.items() if topics is None or c.topic in topics}
    if not wanted:
        return
    stats = summary.statistics
    origin = stats.message_start_time if stats is not None and stats.message_count else None
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        if index.message_index_offsets and wanted.isdisjoint(index.message_index_offsets):
            continue
        # the chunk's log times span [message_start_time, message_end_time]
        if (start is not None and index.message_end_time < start) or (
            end is not None and index.message_start_time >= end
        ):
            continue
        if not _within(index, start, end) and not _indexed_in_window(f, index, wanted, start, end):
            continue  # a label or event widens its span: no wanted message in the window
        try:
            messages = list(chunk_messages(f, index.chunk_start_offset, index.chunk_length, wanted))
        except Exception as e:  # CRC, zstd or a record running past the chunk's end
            damage = Damage(
                index.chunk_start_offset,
                index.chunk_length,
                str(e) or type(e).__name__,
                index.message_start_time,
                index.message_end_time,
                tuple(
                    sorted(
                        summary.channels[c].topic
                        for c in index.message_index_offsets
                        if c in summary.channels
                    )
                ),
            )
            raise CaptureError(_damage_line(Path(f.name), damage.describe(origin))) from None
        for cid, sequence, log_time, publish_time, data in messages:
            if not _in_window(log_time, start, end):
                continue
            channel = summary.channels[cid]
            yield (
                summary.schemas.get(channel.schema_id),
                channel,
                Message(
                    channel_id=cid,
                    sequence=sequence,
                    log_time=log_time,
                    publish_time=publish_time,
                    data=data,
                ),
            )


def _within(index, start: int | None, end: int | None) -> bool:
    """Whether every message of the chunk is logged inside [start, end)."""
    return (start is None or index.message_start_time >= start) and (
        end is None or index.message_end_time < end
    )


def _indexed_in_window(f, index, wanted: set[int], start, end) -> bool:
    """Whether the chunk's message indexes (small records after it, read without
    decompressing it) put a message of a wanted channel in [start, end); True when the
    chunk has no index to tell."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import MessageIndex

    offsets = index.message_index_offsets
    if not offsets:
        return True
    try:
        for cid in wanted & set(offsets):
            f.seek(offsets[cid] + RECORD_HEAD.size)
            records = MessageIndex.read(ReadDataStream(f)).records
            if any(_in_window(t, start, end) for t, _ in records):
                return True
    except Exception:  # a damaged index: the chunk itself is read (its CRC checks it)
        return True
    return False


def chunk_messages(f, offset: int, length: int, wanted: set[int]):
    """(channel id, sequence, log time, publish time, data) of the chunk record at
    `offset`, for the wanted channels. Damage raises (ValueError, zstd's errors). The
    records inside are walked here rather than by mcap's breakup_chunk, which builds an
    object for every message: most are IMU samples a frame reader skips."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Chunk

    f.seek(offset)
    record = f.read(length)
    if len(record) != length:  # the record's head is not read: the index (CRC) says where
        raise ValueError(f"no chunk at byte {offset}")
    chunk = Chunk.read(ReadDataStream(io.BytesIO(memoryview(record)[RECORD_HEAD.size :])))
    if chunk.compression == "zstd":
        import zstandard

        records = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "":
        records = chunk.data
    else:
        raise ValueError(f"chunk compression {chunk.compression!r}: walkcap reads zstd or none")
    if len(records) != chunk.uncompressed_size:
        raise ValueError(
            f"chunk at byte {offset}: {len(records)} bytes, not {chunk.uncompressed_size}"
        )
    if chunk.uncompressed_crc and zlib.crc32(records) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    at, end = 0, len(records)
    while at < end:
        opcode, body_length = RECORD_HEAD.unpack_from(records, at)
        at += RECORD_HEAD.size
        if at + body_length > end:
            raise ValueError(f"chunk at byte {offset}: a record runs past its end")
        if opcode == Opcode.MESSAGE:
            cid, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(records, at)
            if cid in wanted:
                yield (
                    cid,
                    sequence,
                    log_time,
                    publish_time,
                    records[at + _MESSAGE_HEAD.size : at + body_length],
                )
        at += body_length


def log_times(path: Path, complete: bool) -> dict[str, np.ndarray]:
    """Log times per topic from the message indexes: no chunk is decompressed (an
    unfinished file: its messages read)."""
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import MessageIndex

    if not complete:
        return _scan_times(path)
    times: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for channel in summary.channels.values():
            times.setdefault(channel.topic, [])
        for chunk in summary.chunk_indexes:
            if not chunk.message_index_offsets:  # no index: read the chunk itself
                return {k: v for k, v in _scan_times(path).items()}
            for cid, offset in chunk.message_index_offsets.items():
                if cid not in summary.channels:  # a damaged index: read the messages instead
                    return _scan_times(path)
                f.seek(offset + 9)
                index = MessageIndex.read(ReadDataStream(f))
                times[summary.channels[cid].topic].extend(t for t, _ in index.records)
    return {k: np.sort(np.asarray(v, dtype=np.int64)) for k, v in times.items()}


def _scan_times(path: Path) -> dict[str, np.ndarray]:
    times: dict[str, list[int]] = {}
    for _, channel, message in iter_raw(path, False, None):
        times.setdefault(channel.topic, []).append(message.log_time)
    return {k: np.sort(np.asarray(v, dtype=np.int64)) for k, v in times.items()}
