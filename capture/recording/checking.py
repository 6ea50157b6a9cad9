"""The whole-file check: every record of a recording read and its chunks' CRCs checked, the
damage placed in time and topics by the file's chunk index (`walkcap info`, `recover`)."""

from __future__ import annotations

import os
from typing import BinaryIO

from capture.recording._mcap import (
    Damage,
    ScanResult,
    check_magic,
    file_bytes,
    scan,
    summary_damage,
)


def summary_of(stream: BinaryIO):
    """The file's summary (schemas, channels, chunk indexes), None if it has none readable
    or its CRC fails."""
    from mcap.reader import make_reader

    try:
        if summary_damage(file_bytes(stream)):
            return None
        stream.seek(0)
        return make_reader(stream).get_summary()
    except Exception:  # no footer or a damaged summary: the data section is all there is
        return None


def describe_damage(damage: list[Damage], summary) -> None:
    """Fill in the time span and topics of damaged regions from the file's chunk index."""
    if summary is None:
        return
    for d in damage:
        if not d.lost:
            continue
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
