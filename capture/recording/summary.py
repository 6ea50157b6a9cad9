"""What a recording holds, in one typed record: the data behind `walkcap info` and `--json`.

    s = summary(open_recording(path))
    s.state, s.topics[0].rate_hz, s.losses, s.labels
    s.to_json()                                # what `walkcap info --json` prints

Damage is looked for in every chunk (capture.recording._mcap.check), finished file or
not; in a damaged file the labels and events before the damage are listed and the gaps
are not counted (count them on its recovered copy).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from capture.errors import CaptureError
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording._mcap import Damage, check
from capture.recording.gaps import StreamLoss, recording_loss
from capture.recording.lineage import RECORDING, Member, describe
from capture.recording.reader import Recording
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
        return (t_ns - self.start_ns) * 1e-9 if self.start_ns is not None else None

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
    return dt.datetime.fromtimestamp(unix_ns * 1e-9, dt.UTC).isoformat(timespec="milliseconds")


def summary(rec: Recording) -> RecordingSummary:
    """Everything `walkcap info` says about an open recording."""
    damaged = check(rec.path).damaged  # every chunk's CRC, finished file or not
    times = rec.log_times()
    topics = []
    for topic in sorted(rec.topics):
        info = rec.topics[topic]
        t = times.get(topic, [])
        span = (t[-1] - t[0]) * 1e-9 if len(t) > 1 else 0.0
        regular = topic not in (T.LABELS, T.EVENTS)
        rate = (len(t) - 1) / span if span > 0 and regular else None
        topics.append(
            TopicSummary(topic, info.count, rate, info.schema_name, info.message_encoding)
        )
    try:
        losses: dict[str, StreamLoss] | None = recording_loss(rec)
    except CaptureError:  # damaged: counted on the recovered copy
        losses = None
    labels, events, markers = [], {}, []
    small = [t for t in (T.LABELS, T.EVENTS) if t in rec.topics]
    try:
        for m in rec.messages(small):
            if m.topic == T.LABELS:
                labels.append(L.change_from_message(m.data))
            else:
                events[m.data["kind"]] = events.get(m.data["kind"], 0) + 1
                if m.data["kind"] == "marker":
                    markers.append((int(m.data["time_ns"]), m.data.get("message", "")))
    except CaptureError:  # damaged: the labels and events before the damage
        if not damaged:
            raise
    labels = L.in_time_order(labels)
    in_force = set(L.effective_changes(labels))
    return RecordingSummary(
        path=rec.path,
        complete=rec.complete,
        reason=rec.reason,
        damaged=damaged,
        size_bytes=rec.size,
        duration_s=rec.duration_s,
        member=describe(rec),
        trial=rec.trial,
        start_ns=rec.start_ns,
        end_ns=rec.end_ns,
        unix_offset_ns=rec.unix_offset_ns,
        topics=topics,
        losses=losses,
        frame_flags=_frame_flags(rec),
        processed_frames=rec.topics[T.PREPROCESS].count if T.PREPROCESS in rec.topics else None,
        labels=labels,
        in_reference=[c in in_force for c in labels],
        events=events,
        markers=sorted(markers),
        metadata=rec.metadata,
        attachments=dict(rec.attachment_sizes),
    )


def _frame_flags(rec: Recording) -> dict[str, int] | None:
    """How many frames have each preprocessing flag (why their image is empty); None when
    the file has no /camera/preprocess. Damage ends the count where it starts."""
    if T.PREPROCESS not in rec.topics:
        return None
    counts: dict[str, int] = {}
    try:
        for m in rec.messages([T.PREPROCESS]):
            flag = m.data.get("flag") or ""
            if flag:
                counts[flag] = counts.get(flag, 0) + 1
    except CaptureError:
        pass  # the damage is listed on its own line
    return counts
