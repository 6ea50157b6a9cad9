"""Rebuilding cut-off recordings: `recover` writes what the scan (capture.recording._mcap)
found into a new, indexed file and merges the journal: labels and operator markers missing
from the file are added.
"""

from __future__ import annotations

import logging
import os
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import (
    Attachment,
    Channel,
    Header,
    Message,
    Metadata,
    Schema,
)

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording._mcap import Damage, ScanResult, check_magic, scan
from capture.recording.checking import describe_damage, summary_of
from capture.recording.copy import RecordingCopy
from capture.recording.journal import check_journal, journal_path
from capture.recording.lineage import RECOVERED, derivation
from capture.recording.reader import open_recording
from devices import clock
from devices.files import check_replaceable

log = logging.getLogger(__name__)


@dataclass
class RecoveryReport:
    source: str
    output: str
    complete: bool  # the source was a finished file, nothing in it damaged
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
    finished: bool = False  # the source ends with its footer (damaged or not)
    journal_skipped: list[str] = field(default_factory=list)  # "line N: why"

    @property
    def salvaged(self) -> bool:
        return self.messages > 0

    @property
    def duration_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return clock.seconds(self.last_ns - self.first_ns)


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
    journal_read = check_journal(jpath)
    entries = journal_read.entries

    result = ScanResult()
    seen: dict[str, set] = {T.LABELS: set(), T.EVENTS: set()}
    first = last = None
    unknown_channel = 0
    tmp = out.with_name(out.name + ".partial")
    try:
        with open(source, "rb") as f, open(tmp, "wb") as g:
            # A damaged chunk can hold the schema and channel records of later chunks: a
            # finished file's summary repeats them.
            summary = summary_of(f)
            copy = RecordingCopy(g)
            for record in scan(f, result):
                if isinstance(record, Header):
                    copy.start(profile=record.profile, library=record.library)
                    continue
                if not copy.started:
                    copy.start()
                if isinstance(record, Schema):
                    copy.schema(record)
                elif isinstance(record, Channel):
                    copy.channel(record)
                elif isinstance(record, Message):
                    if not copy.knows(record.channel_id) and summary is not None:
                        channel = summary.channels.get(record.channel_id)
                        if channel is not None:
                            copy.channel(channel, summary.schemas.get(channel.schema_id))
                    if not copy.knows(record.channel_id):
                        unknown_channel += 1  # its channel record was lost: undecodable
                        continue
                    copy.message(record)
                    topic = copy.topics[record.channel_id]
                    if topic in seen:
                        seen[topic].add(_key(topic, record.data))
                    if topic not in (T.LABELS, T.EVENTS):
                        first = record.log_time if first is None else min(first, record.log_time)
                        last = record.log_time if last is None else max(last, record.log_time)
                elif isinstance(record, Metadata):
                    copy.metadata(record.name, record.metadata)
                elif isinstance(record, Attachment):
                    copy.attachment(
                        record.create_time,
                        record.log_time,
                        record.name,
                        record.media_type,
                        record.data,
                    )
            if not copy.started:
                copy.start()
            if result.records == 0 and not entries:
                g.close()
                tmp.unlink()
                raise CaptureError(
                    f"{source}: nothing to recover ({result.reason or 'no readable record'})"
                )
            describe_damage(result.damaged, summary)
            labels_added, events_added = _merge_journal(copy, entries, seen)
            copy.metadata(
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
                    "journal_skipped": "; ".join(journal_read.skipped),
                    "labels_added_from_journal": str(labels_added),
                    "events_added_from_journal": str(events_added),
                },
            )
            _add_derivation(copy, source, result)
            copy.finish()
            g.flush()
            os.fsync(g.fileno())
        os.replace(tmp, out)
    except BaseException as e:
        tmp.unlink(missing_ok=True)  # half a copy is no copy: nothing is left behind
        if isinstance(e, OSError) and not isinstance(e, FileNotFoundError):
            why = e.strerror or str(e)
            raise CaptureError(
                f"{out}: not written ({why}); nothing of it is left, {source} is unchanged"
            ) from None
        raise
    counts = copy.counts
    return RecoveryReport(
        source=str(source),
        output=str(out),
        complete=result.complete,
        finished=result.finished,
        journal_skipped=journal_read.skipped,
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


def _key(topic: str, data: bytes | dict) -> tuple:
    import json

    m = json.loads(data) if isinstance(data, (bytes, bytearray)) else data
    if topic == T.LABELS:
        return (int(m.get("time_ns", 0)), m.get("mode", ""), m.get("source", ""))
    return (int(m.get("time_ns", 0)), m.get("device", ""), m.get("kind", ""), m.get("message", ""))


def _merge_journal(
    copy: RecordingCopy, entries: list[dict], seen: dict[str, set]
) -> tuple[int, int]:
    """Add the journal's labels and markers that the file does not have."""
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
        copy.add(topic, message)
        added[topic] += 1
    return added[T.LABELS], added[T.EVENTS]


def _add_derivation(copy: RecordingCopy, source: Path, result: ScanResult) -> None:
    """The recovered copy's own identity and lineage (capture.corpus.selection)."""
    how = f"recovered: {result.valid_end} of {result.size} bytes readable"
    if result.reason:
        how += f" ({result.reason})"
    new_id = str(uuid.uuid4())
    try:
        record = derivation(open_recording(source), new_id, RECOVERED, how)
    except CaptureError:  # its metadata is unreadable: the source is known by its name
        record = {"id": new_id, "kind": RECOVERED, "source_id": "", "source_name": source.name}
        record["how"] = how
    copy.metadata("derivation", T.encode_metadata(record))
