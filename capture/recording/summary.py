"""What a recording holds, in one typed record: the data behind `walkcap info` and `--json`.

    s = summary(open_recording(path))
    s.state, s.topics[0].rate_hz, s.losses, s.labels
    s.to_json()                                # what `walkcap info --json` prints

Damage is looked for in every chunk: in a finished file with chunk digests, by the CRC of
every byte the writer wrote (capture.recording.chunk_digests), which also carries the gaps,
flags, labels and events, so no chunk is decompressed; in any other file, or one whose
digests do not prove it, by the reading of capture.recording.checking.check, finished
file or not, in the one pass that also counts gaps. In a damaged file the labels
and events before the damage are listed and the gaps are not counted (count them on its
recovered copy). Memory stays the same whatever the file's length.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture.recording import chunk_digests as CD
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording._mcap import Damage, ScanResult, scan
from capture.recording.checking import describe_damage, summary_of
from capture.recording.gaps import StreamLoss, loss_counters
from capture.recording.lineage import RECORDING, Member, describe
from capture.recording.messages import damage_is_an_error
from capture.recording.metadata import Metadata
from capture.recording.reader import Recording
from devices import clock
from inference.preprocess import BAD_ORIENTATION, STALE_ORIENTATION


@dataclass
class TopicSummary:
    topic: str
    messages: int
    rate_hz: float | None  # None for labels and events, and for fewer than two messages
    schema: str
    encoding: str


@dataclass
class RecordingSummary:
    path: Path
    complete: bool  # finished and nothing damaged in its index
    reason: str  # why an unfinished file stops where it does
    damaged: list[Damage]  # every damaged region, finished file or not
    size_bytes: int
    duration_s: float
    member: Member  # identity and lineage
    start_ns: int | None  # session clock
    end_ns: int | None
    unix_offset_ns: int | None
    topics: list[TopicSummary]  # by topic name
    losses: dict[str, StreamLoss] | None  # per sensor topic; None: damaged, not counted
    frame_flags: dict[str, int] | None  # frames per preprocessing flag; None: no topic
    processed_frames: int | None  # /camera/preprocess messages; None: no topic
    labels: list[L.LabelChange]  # every change, undos included, in time order
    in_reference: list[bool]  # per change: it defines the reference (labels.effective_changes)
    events: dict[str, int]  # per kind
    markers: list[tuple[int, str]]  # (time_ns, note), in time order
    metadata: dict[str, dict[str, Any]]
    attachments: dict[str, int]  # name -> bytes
    trial: tuple[str, str, int | None]  # (subject, condition, trial)

    @property
    def meta(self) -> Metadata:
        """The metadata records typed (capture.recording.metadata)."""
        return Metadata.from_dict(self.metadata)

    @property
    def stale_orientation_frames(self) -> int:
        return (self.frame_flags or {}).get(STALE_ORIENTATION, 0)

    @property
    def bad_orientation_frames(self) -> int:
        """Frames whose orientation is no rotation (left undecided, as stale ones are)."""
        return (self.frame_flags or {}).get(BAD_ORIENTATION, 0)

    @property
    def reference(self) -> list[L.LabelChange]:
        """The label changes as they stand: undos applied, corrections laid over."""
        return L.effective_changes(self.labels)

    @property
    def undos(self) -> int:
        return sum(1 for _, _, source in self.labels if L.is_undo(source))

    def at_s(self, t_ns: int) -> float | None:
        """Seconds from the recording's start."""
        return clock.seconds(t_ns - self.start_ns) if self.start_ns is not None else None

    def unix_time_ns(self, t_ns: int) -> int | None:
        return None if self.unix_offset_ns is None else t_ns + self.unix_offset_ns

    def when(self, t_ns: int) -> dict:
        unix = self.unix_time_ns(t_ns)
        return {"session_ns": t_ns, "unix_ns": unix, "utc": _iso(unix)}

    def to_json(self) -> dict:
        """JSON-ready data: times on the session clock (ns) with their Unix time (ns) and
        UTC ISO text, metadata typed."""
        m = self.member
        subject, condition, trial = self.trial
        if self.losses is None:
            gaps = late = None
        else:
            gaps = {
                topic: [
                    {"start_s": self.at_s(g.start_ns), "length_s": g.length_s, "missing": g.missing}
                    for g in loss.gaps
                ]
                for topic, loss in self.losses.items()
            }
            late = {
                topic: [
                    {"start_s": self.at_s(x.start_ns), "length_s": x.length_s} for x in loss.late
                ]
                for topic, loss in self.losses.items()
            }
        return {
            "path": str(self.path),
            "complete": self.complete,
            "reason": self.reason,
            "damaged": [
                {
                    "offset": d.offset,
                    "bytes": d.length,
                    "reason": d.reason,
                    "start_ns": d.start_ns,
                    "end_ns": d.end_ns,
                    "topics": list(d.topics),
                }
                for d in self.damaged
            ],
            "size_bytes": self.size_bytes,
            "bytes_per_s": self.size_bytes / self.duration_s if self.duration_s > 0 else None,
            "id": m.id,
            "kind": m.kind,
            "source": {"id": m.source_id, "name": m.source_name, "how": m.how}
            if m.kind != RECORDING
            else None,
            "trial": {"subject": subject, "condition": condition, "trial": trial},
            "start": self.when(self.start_ns) if self.start_ns is not None else None,
            "end": self.when(self.end_ns) if self.end_ns is not None else None,
            "duration_s": self.duration_s,
            "unix_offset_ns": self.unix_offset_ns,
            "topics": {
                t.topic: {
                    "messages": t.messages,
                    "rate_hz": t.rate_hz,
                    "schema": t.schema,
                    "encoding": t.encoding,
                }
                for t in self.topics
            },
            "gaps": gaps,
            "late": late,
            "stale_orientation_frames": self.stale_orientation_frames,
            "bad_orientation_frames": self.bad_orientation_frames,
            "labels": [
                {**self.when(t), "mode": mode, "source": source, "in_reference": used}
                for (t, mode, source), used in zip(self.labels, self.in_reference, strict=True)
            ],
            "events": self.events,
            "markers": [{**self.when(t), "note": note} for t, note in self.markers],
            "metadata": T.jsonable(self.metadata),
            "attachments": dict(self.attachments),
        }


def _iso(unix_ns: int | None) -> str | None:
    if unix_ns is None:
        return None
    return dt.datetime.fromtimestamp(clock.seconds(unix_ns), dt.UTC).isoformat(
        timespec="milliseconds"
    )


def summary(rec: Recording) -> RecordingSummary:
    """Everything `walkcap info` says about an open recording. Counts, times, topics,
    metadata and attachments come from what `open_recording` read (a finished file's
    summary section); damage, rates, gaps, labels, events and the frames' flags from the
    writer's chunk digests once they prove the file (`_from_digests`), else from one pass
    over the records (`_read_through`) that keeps a few numbers per topic."""
    seen = _from_digests(rec) or _read_through(rec)
    topics = []
    for topic in sorted(rec.topics):
        info = rec.topics[topic]
        n, first, last = seen.times.get(topic, (0, 0, 0))
        span = clock.seconds(last - first) if n > 1 else 0.0
        regular = topic not in (T.LABELS, T.EVENTS)
        rate = (n - 1) / span if span > 0 and regular else None
        topics.append(
            TopicSummary(topic, info.count, rate, info.schema_name, info.message_encoding)
        )
    labels = L.in_time_order(seen.labels)
    in_force = set(L.effective_changes(labels))
    return RecordingSummary(
        path=rec.path,
        complete=rec.complete,
        reason=rec.reason,
        damaged=seen.damaged,
        size_bytes=rec.size,
        duration_s=rec.duration_s,
        member=describe(rec),
        trial=rec.trial,
        start_ns=rec.start_ns,
        end_ns=rec.end_ns,
        unix_offset_ns=rec.unix_offset_ns,
        topics=topics,
        losses=seen.losses,
        frame_flags=seen.flags if T.PREPROCESS in rec.topics else None,
        processed_frames=rec.topics[T.PREPROCESS].count if T.PREPROCESS in rec.topics else None,
        labels=labels,
        in_reference=[c in in_force for c in labels],
        events=seen.events,
        markers=sorted(seen.markers),
        metadata=rec.metadata,
        attachments=dict(rec.attachment_sizes),
    )


@dataclass
class _Seen:
    """What one pass over a file's records finds: a few numbers per topic."""

    damaged: list[Damage]
    times: dict[str, tuple[int, int, int]]  # topic -> (messages read, first, last log time)
    losses: dict[str, StreamLoss] | None  # None: damaged, not counted
    flags: dict[str, int]
    labels: list[L.LabelChange]
    events: dict[str, int]
    markers: list[tuple[int, str]]


def _read_through(rec: Recording) -> _Seen:
    """Every record in file order, every chunk's CRC checked (capture.recording._mcap.scan,
    the same reading as `check`), finished file or not, one chunk in memory at a time.
    Labels, events and flags are read up to the first damage, where every reader stops;
    the gaps of a damaged file are not counted."""
    from mcap.records import Channel, Message, Schema

    result = ScanResult()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    times: dict[int, list[int]] = {}
    counters = loss_counters(rec.meta.devices, rec.topics)
    decode = rec.decoder()
    decoded = {T.LABELS, T.EVENTS, T.PREPROCESS}
    flags: dict[str, int] = {}
    labels, events, markers = [], {}, []
    with open(rec.path, "rb") as f, damage_is_an_error(rec.path):
        for record in scan(f, result):
            if not isinstance(record, Message):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                continue
            t = times.get(record.channel_id)
            if t is None:
                times[record.channel_id] = [1, record.log_time, record.log_time]
            else:
                t[0] += 1
                t[1] = min(t[1], record.log_time)
                t[2] = max(t[2], record.log_time)
            channel = channels.get(record.channel_id)
            if channel is None or result.lost:  # after damage: counted, not read
                continue
            topic = channel.topic
            if topic in counters:
                counters[topic].add(record.sequence, record.publish_time, record.log_time)
            elif topic in decoded:
                m = decode(schemas.get(channel.schema_id), channel, record)
                if topic == T.PREPROCESS:
                    flag = m.data.get("flag") or ""
                    if flag:
                        flags[flag] = flags.get(flag, 0) + 1
                else:
                    _take(m, labels, events, markers)
        if result.damaged:
            describe_damage(result.damaged, summary_of(f))
    by_topic: dict[str, tuple[int, int, int]] = {}
    for cid, (n, first, last) in times.items():
        if cid in channels:
            by_topic[channels[cid].topic] = (n, first, last)
    losses = None if result.lost else {topic: c.loss() for topic, c in counters.items()}
    return _Seen(result.damaged, by_topic, losses, flags, labels, events, markers)


def _take(m, labels: list, events: dict, markers: list) -> None:
    """A decoded label or event message into what `info` lists."""
    if m.topic == T.LABELS:
        labels.append(L.change_from_message(m.data))
    else:
        events[m.data["kind"]] = events.get(m.data["kind"], 0) + 1
        if m.data["kind"] == "marker":
            markers.append((int(m.data["time_ns"]), m.data.get("message", "")))


def _from_digests(rec: Recording) -> _Seen | None:
    """What `_read_through` finds, from a finished file's chunk digests once its bytes are
    proven to be the writer's (capture.recording.chunk_digests); None: read it through."""
    from mcap.reader import make_reader
    from mcap.records import Message

    if not rec.complete or rec.damaged:
        return None
    with open(rec.path, "rb") as f:
        try:
            reader = make_reader(f)
            found = reader.get_summary()
            stored = [m for m in reader.iter_metadata() if m.name == CD.CHUNK_DIGESTS]
        except Exception:  # the reader saw a readable summary; any doubt: the scan decides
            return None
        parsed = CD.parse(stored[0].metadata) if found is not None and len(stored) == 1 else None
        if parsed is None:
            return None
        regions, digest = parsed
        indexes = (found.metadata_indexes, found.chunk_indexes, found.attachment_indexes)
        if not CD.proven(f, rec.size, regions, *indexes):
            return None
    channels = {c.topic: c for c in found.channels.values()}
    decode = rec.decoder()
    labels, events, markers = [], {}, []
    for topic, log_time, publish_time, sequence, data in digest.kept:
        channel = channels.get(topic)
        if channel is None:
            return None
        record = Message(
            channel_id=channel.id,
            sequence=sequence,
            log_time=log_time,
            publish_time=publish_time,
            data=data,
        )
        m = decode(found.schemas.get(channel.schema_id), channel, record)
        _take(m, labels, events, markers)
    counters = loss_counters(rec.meta.devices, rec.topics)
    losses = {topic: digest.losses.get(topic, StreamLoss()) for topic in counters}
    return _Seen([], digest.times, losses, dict(digest.flags), labels, events, markers)
