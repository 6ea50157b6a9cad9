"""Chunk digests: what `walkcap info` reads from a finished recording instead of its chunks.

The writer keeps, as it writes, a CRC-32 of every region of the file it writes at once
(the header with the session's metadata and attachments, then each chunk with its message
indexes and whatever records precede it) and, per topic, the figures `info` otherwise
gathers by decompressing every chunk: message count and log-time span, the sensor
streams' gaps and late deliveries (capture.recording.gaps, counted on the messages as the
file holds them), the frames' preprocessing flags, and the few label and event messages
themselves. On finishing, it puts them in one metadata record, `chunk_digests` (format
version 4 on), sealed by its record digest like every other metadata record.

A reader proves the file is as the writer left it by the regions alone: they tile the
file from its first byte to the digest's own seal with no gap, every region's CRC over
the bytes on disk matches, and the records after them are the metadata records the
summary indexes and the data end, up to the summary (whose CRC the footer carries). Then
the stored figures stand for the chunks' contents, read without decompressing one. Any
mismatch, a file without the record (older, unfinished, copied) or one whose record
digests fail, is read by the streaming scan, which also says what is damaged and where.
"""

from __future__ import annotations

import base64
import json
import struct
import zlib
from dataclasses import dataclass
from typing import BinaryIO

import orjson

from capture.recording import topics as T
from capture.recording._mcap import MAGIC
from capture.recording.gaps import TOPICS as SENSOR_STREAMS
from capture.recording.gaps import Gap, Late, RecordedLoss, StreamLoss, recorded_periods
from capture.recording.metadata import DevicesRecord

CHUNK_DIGESTS = "chunk_digests"  # the metadata record that holds them
FIRST_VERSION = 4  # the format version that writes them (capture.recording.versions)
KEPT = (T.LABELS, T.EVENTS)  # topics whose messages are kept whole (few, read by `info`)
_READ = 8 << 20  # bytes read at a time to check a region


class Tally:
    """The writer's side: regions and per-topic figures, gathered as the file is written."""

    def __init__(self, metadata: dict[str, dict]) -> None:
        self._periods = recorded_periods(DevicesRecord.from_dict(metadata.get("devices")))
        self.regions: list[tuple[int, int, int]] = []  # (offset, length, CRC-32)
        self._times: dict[str, list[int]] = {}  # topic -> [messages, first, last log time]
        self._losses: dict[str, RecordedLoss | None] = {}  # None: no configured rate
        self._flags: dict[str, int] = {}
        self._kept: list[list] = []  # [topic, log time, publish time, sequence, payload]

    def region(self, offset: int, length: int, crc: int) -> None:
        if length:
            self.regions.append((offset, length, crc))

    def message(self, topic: str, log_time: int, publish_time: int, sequence: int, data) -> None:
        """One message as the file holds it (sequence as stored: 32 bits)."""
        t = self._times.get(topic)
        if t is None:
            self._times[topic] = [1, log_time, log_time]
        else:
            t[0] += 1
            t[1] = min(t[1], log_time)
            t[2] = max(t[2], log_time)
        stream = SENSOR_STREAMS.get(topic)
        if stream is not None:
            if topic not in self._losses:
                period = self._periods.get(topic)  # without it the count needs every item
                self._losses[topic] = RecordedLoss(stream, period) if period else None
            loss = self._losses[topic]
            if loss is not None:
                loss.add(sequence, publish_time, log_time)
        elif topic == T.PREPROCESS:
            flag = orjson.loads(data).get("flag") or ""
            if flag:
                self._flags[flag] = self._flags.get(flag, 0) + 1
        elif topic in KEPT:
            payload = base64.b64encode(bytes(data)).decode()
            self._kept.append([topic, log_time, publish_time, sequence, payload])

    def values(self) -> dict[str, str]:
        """The `chunk_digests` record's values (MCAP metadata: text)."""
        losses = {}
        for topic, loss in self._losses.items():
            if loss is None:  # no configured rate: info counts it from the file
                losses = None
                break
            found = loss.loss()
            losses[topic] = {
                "gaps": [[g.start_ns, g.length_s, g.missing] for g in found.gaps],
                "late": [[x.start_ns, x.length_s] for x in found.late],
            }
        dump = json.dumps
        return {
            "regions": dump(self.regions, separators=(",", ":")),
            "times": dump(self._times, separators=(",", ":")),
            "losses": dump(losses, separators=(",", ":")),
            "flags": dump(self._flags, separators=(",", ":")),
            "kept": dump(self._kept, separators=(",", ":")),
        }


@dataclass
class Digest:
    """A finished file's stored figures, once its regions are proven."""

    times: dict[str, tuple[int, int, int]]  # topic -> (messages, first, last log time)
    losses: dict[str, StreamLoss]
    flags: dict[str, int]
    kept: list[tuple[str, int, int, int, bytes]]  # labels and events, in file order


def parse(values: dict[str, str]) -> tuple[list, Digest] | None:
    """(regions, figures) from a `chunk_digests` record; None if it does not read as one."""
    try:
        regions = [tuple(int(v) for v in r) for r in json.loads(values["regions"])]
        raw_losses = json.loads(values["losses"])
        if raw_losses is None:
            return None
        losses = {
            topic: StreamLoss(
                [Gap(int(a), float(b), int(c)) for a, b, c in found["gaps"]],
                [Late(int(a), float(b)) for a, b in found["late"]],
            )
            for topic, found in raw_losses.items()
        }
        times = {
            k: (int(n), int(a), int(b)) for k, (n, a, b) in json.loads(values["times"]).items()
        }
        flags = {str(k): int(v) for k, v in json.loads(values["flags"]).items()}
        kept = [
            (str(topic), int(log), int(pub), int(seq), base64.b64decode(payload))
            for topic, log, pub, seq, payload in json.loads(values["kept"])
        ]
    except (KeyError, TypeError, ValueError):
        return None
    return regions, Digest(times, losses, flags, kept)


_DATA_END = struct.Struct("<BQI")  # opcode 0x0F, length 4, data section CRC
_FOOTER = struct.Struct("<BQQQI")  # opcode 0x02, length 20, summary start, offsets, CRC


def proven(f: BinaryIO, size: int, regions: list, metadata_indexes, chunk_indexes, attachments):
    """Whether the file's bytes are the ones the writer digested: regions tile the file from
    its start to the seal of `chunk_digests`, each CRC matches, and what follows is indexed
    metadata records and the data end up to the summary."""
    if not regions or regions[0][0] != 0:
        return False
    end = 0
    for offset, length, _ in regions:
        if offset != end or length <= 0:
            return False
        end = offset + length
    # after the regions: the digest's seal, the digest, the closing records, in one run
    tail = sorted((i for i in metadata_indexes if i.offset >= end), key=lambda i: i.offset)
    if not any(i.name == CHUNK_DIGESTS for i in tail):
        return False
    at = end
    for i in tail:
        if i.offset != at:
            return False
        at += i.length
    if any(i.offset + i.length > end for i in metadata_indexes if i.offset < end):
        return False
    for c in chunk_indexes:
        if c.chunk_start_offset + c.chunk_length + c.message_index_length > end:
            return False
    if any(a.offset + a.length > end for a in attachments):
        return False
    f.seek(size - len(MAGIC) - _FOOTER.size)
    footer = f.read(_FOOTER.size)
    if len(footer) != _FOOTER.size:
        return False
    opcode, _, summary_start, _, _ = _FOOTER.unpack(footer)
    f.seek(at)
    data_end = f.read(_DATA_END.size)
    if opcode != 0x02 or len(data_end) != _DATA_END.size:
        return False
    op, length, _ = _DATA_END.unpack(data_end)
    if op != 0x0F or length != 4 or at + _DATA_END.size != summary_start:
        return False
    return _crcs_match(f, regions)


def _crcs_match(f: BinaryIO, regions: list) -> bool:
    buffer = bytearray(_READ)
    view = memoryview(buffer)
    f.seek(0)
    for _, length, want in regions:
        crc, left = 0, length
        while left:
            n = f.readinto(view[: min(left, _READ)])
            if not n:
                return False
            crc = zlib.crc32(view[:n], crc)
            left -= n
        if crc != want:
            return False
    return True
