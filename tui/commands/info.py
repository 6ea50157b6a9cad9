"""`walkcap info`: describe a recording: topics, counts, rates, gaps, metadata"""

from __future__ import annotations

import datetime as dt
import json

HELP = "describe a recording: topics, counts, rates, gaps, metadata"


def add_arguments(parser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="MCAP recording(s)")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print JSON (one object per file, in a list) with typed metadata",
    )


def run(args, config) -> int:
    from capture.recording.reader import open_recording

    if args.json:
        data = [summary(open_recording(path)) for path in args.files]
        print(json.dumps(data, indent=2))
        return 0
    for i, path in enumerate(args.files):
        if i:
            print()
        print("\n".join(describe(open_recording(path))))
    return 0


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def _wall(rec, t_ns: int) -> str:
    """Clock time (local, with its zone) of a session-clock time."""
    offset = rec.unix_offset_ns
    if offset is None:
        return f"{t_ns * 1e-9:.3f} s (session clock)"
    return _clock(t_ns + offset)


def _clock(unix_ns: int) -> str:
    return dt.datetime.fromtimestamp(unix_ns * 1e-9).astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")


def _iso(unix_ns: int | None) -> str | None:
    if unix_ns is None:
        return None
    return dt.datetime.fromtimestamp(unix_ns * 1e-9, dt.UTC).isoformat(timespec="milliseconds")


def describe(rec) -> list[str]:
    """The recording in a few readable lines."""
    from capture.errors import CaptureError
    from capture.recording import check, lineage
    from capture.recording import topics as T
    from capture.recording.gaps import recording_loss
    from capture.recording.reader import effective_changes, is_undo

    lines = [str(rec.path)]
    damaged = check(rec.path).damaged  # every chunk's CRC, finished file or not
    if damaged:
        lines.append(
            f"  state       damaged: {len(damaged)} region(s), "
            f"{sum(d.length for d in damaged if d.lost)} bytes unreadable; "
            f"`walkcap recover {rec.path}` copies every intact message"
        )
        for d in damaged:
            lines.append(f"    damaged   {d.describe(rec.start_ns)}")
    elif rec.complete:
        lines.append("  state       complete")
    else:
        lines.append(
            f"  state       unfinished ({rec.reason}): readable here; "
            f"`walkcap recover {rec.path}` writes an indexed copy"
        )
    rate = f" ({_size(rec.size / rec.duration_s)}/s)" if rec.duration_s > 0 else ""
    lines.append(f"  size        {_size(rec.size)}{rate}")
    member = lineage.describe(rec)
    subject, condition, trial = rec.trial
    lines.append(f"  trial       {member.trial_name}; id {member.id}")
    if member.kind != lineage.RECORDING:
        lines.append(
            f"  derived     {member.kind} of {member.source_name or '?'}"
            + (f" (id {member.source_id})" if member.source_id else "")
            + (f": {member.how}" if member.how else "")
        )
    if rec.start_ns is not None:
        lines.append(
            f"  time        {_wall(rec, rec.start_ns)} -> {_wall(rec, rec.end_ns)}, "
            f"{rec.duration_s:.1f} s"
        )
        lines.append(
            f"  session     {rec.start_ns * 1e-9:.3f} -> {rec.end_ns * 1e-9:.3f} s "
            "(session clock: the message times; + unix_offset_ns = Unix time)"
        )
    times = rec.log_times()
    lines.append("  topics      messages    rate  schema" if rec.topics else "  topics      none")
    for topic in sorted(rec.topics):
        info = rec.topics[topic]
        t = times.get(topic, [])
        span = (t[-1] - t[0]) * 1e-9 if len(t) > 1 else 0.0
        regular = topic not in (T.LABELS, T.EVENTS)
        hz = f"{(len(t) - 1) / span:6.1f} Hz" if span > 0 and regular else "      - "
        lines.append(f"    {topic:<22} {info.count:7d} {hz}  {info.schema_name}")
    gaps, late = [], []
    try:
        losses = recording_loss(rec)
    except CaptureError:  # damaged: counted on the recovered copy
        losses = {}
        gaps.append("not counted (the file is damaged; count them on its recovered copy)")
    for topic, loss in losses.items():
        if loss.gaps:
            g = max(loss.gaps, key=lambda g: g.length_s)
            at = (g.start_ns - rec.start_ns) * 1e-9 if rec.start_ns is not None else 0.0
            gaps.append(
                f"{topic} {len(loss.gaps)}, {loss.missing} missing "
                f"(longest {g.length_s:.2f} s at +{at:.1f} s)"
            )
        else:
            gaps.append(f"{topic} none")
        if loss.late:
            late.append(f"{topic} {len(loss.late)} (longest {loss.longest_late_s:.2f} s)")
    if gaps:
        lines.append("  gaps        " + "; ".join(gaps))  # data the devices sent, not here
    if late:
        lines.append("  late        " + "; ".join(late) + ": delivered late, nothing lost")
    flags = frame_flags(rec)
    if flags is not None:
        stale = flags.get(STALE_ORIENTATION, 0)
        empty = ", ".join(f"{k} {v}" for k, v in sorted(flags.items()) if k != STALE_ORIENTATION)
        lines.append(
            f"  frames      {rec.topics[T.PREPROCESS].count} processed; stale orientation "
            f"{stale} (no image, no decision)" + (f"; no image: {empty}" if empty else "")
        )
    small = [t for t in (T.LABELS, T.EVENTS) if t in rec.topics]
    labels, kinds, markers = [], {}, []
    try:
        for m in rec.messages(small):
            if m.topic == T.LABELS:
                d = m.data
                labels.append((int(d["time_ns"]), d.get("mode", "") or "", d.get("source", "")))
            else:
                kinds[m.data["kind"]] = kinds.get(m.data["kind"], 0) + 1
                if m.data["kind"] == "marker":
                    markers.append((int(m.data["time_ns"]), m.data.get("message", "")))
    except CaptureError:  # damaged: the labels and events before the damage are listed
        if not damaged:
            raise
    if labels:
        # the modes as they stand: an undone change (and the undo) is no mode of the trial
        sequence = " ".join(mode or "-" for _, mode, _ in effective_changes(labels))
        undos = sum(1 for _, _, source in labels if is_undo(source))
        undone = f" ({undos} undo(s) applied: what they took back is left out)" if undos else ""
        lines.append(f"  labels      {len(labels)} changes{undone}: {_clip(sequence)}")
    if kinds:
        lines.append("  events      " + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))
    for t, note in sorted(markers):
        at = (t - rec.start_ns) * 1e-9 if rec.start_ns is not None else t * 1e-9
        lines.append(f"  marker      +{at:.1f} s  {_clip(note or 'marker')}")
    lines.append("  metadata")
    for name, values in rec.metadata.items():
        if name == "recording":
            values = {k: v for k, v in values.items() if k != "topics"}
        text = ", ".join(f"{k}={_short(v)}" for k, v in values.items() if v not in ("", None))
        lines.append(f"    {name:<11} {text}")
    if rec.attachment_sizes:
        lines.append(
            "  attachments "
            + ", ".join(f"{name} ({_size(n)})" for name, n in rec.attachment_sizes.items())
        )
    return lines


STALE_ORIENTATION = "stale_orientation"  # inference.preprocess's flag of an undecided frame


def frame_flags(rec) -> dict[str, int] | None:
    """How many frames have each preprocessing flag (why their image is empty); None when
    the file has no /camera/preprocess. Damage ends the count where it starts."""
    from capture.errors import CaptureError
    from capture.recording import topics as T

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


def recorded_periods(metadata: dict) -> dict[str, float]:
    """Each sensor topic's configured period from the file's metadata."""
    from capture.recording.gaps import recorded_periods as periods

    return periods(metadata)


def _short(value, width: int = 60) -> str:
    if isinstance(value, str):
        try:
            value = json.loads(value)  # an older file's JSON text
        except ValueError:
            return _clip(value, width)
    if isinstance(value, (dict, list)):
        return _clip(json.dumps(value, separators=(",", ":")), width)
    return _clip(str(value), width)


def _clip(text: str, width: int = 100) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."


def summary(rec) -> dict:
    """Everything `describe` shows, as JSON-ready data: times on the session clock (ns)
    with their Unix time (ns) and UTC ISO text, metadata typed."""
    from capture.errors import CaptureError
    from capture.recording import check, lineage
    from capture.recording import topics as T
    from capture.recording.gaps import recording_loss
    from capture.recording.reader import effective_changes

    member = lineage.describe(rec)
    subject, condition, trial = rec.trial
    times = rec.log_times()
    topics = {}
    for topic in sorted(rec.topics):
        info = rec.topics[topic]
        t = times.get(topic, [])
        span = (t[-1] - t[0]) * 1e-9 if len(t) > 1 else 0.0
        regular = topic not in (T.LABELS, T.EVENTS)
        topics[topic] = {
            "messages": info.count,
            "rate_hz": (len(t) - 1) / span if span > 0 and regular else None,
            "schema": info.schema_name,
            "encoding": info.message_encoding,
        }

    def at(t: int) -> float | None:
        return (t - rec.start_ns) * 1e-9 if rec.start_ns is not None else None

    gaps, late = {}, {}
    try:
        losses = recording_loss(rec)
    except CaptureError:  # damaged: counted on the recovered copy ("damaged" says where)
        losses = {}
        gaps = late = None
    for topic, loss in losses.items():
        gaps[topic] = [
            {"start_s": at(g.start_ns), "length_s": g.length_s, "missing": g.missing}
            for g in loss.gaps
        ]
        late[topic] = [{"start_s": at(x.start_ns), "length_s": x.length_s} for x in loss.late]
    flags = frame_flags(rec)
    labels, events, markers = [], {}, []
    small = [t for t in (T.LABELS, T.EVENTS) if t in rec.topics]
    damaged = check(rec.path).damaged  # every chunk's CRC, finished file or not
    try:
        for m in rec.messages(small):
            if m.topic == T.LABELS:
                labels.append(
                    (int(m.data["time_ns"]), m.data.get("mode", ""), m.data.get("source", ""))
                )
            else:
                events[m.data["kind"]] = events.get(m.data["kind"], 0) + 1
                if m.data["kind"] == "marker":
                    markers.append((int(m.data["time_ns"]), m.data.get("message", "")))
    except CaptureError:  # damaged: the labels and events before the damage
        if not damaged:
            raise
    labels.sort(key=lambda c: c[0])
    in_force = set(effective_changes(labels))

    def when(t):
        unix = rec.unix_time_ns(t)
        return {"session_ns": t, "unix_ns": unix, "utc": _iso(unix)}

    return {
        "path": str(rec.path),
        "complete": rec.complete,
        "reason": rec.reason,
        "damaged": [
            {
                "offset": d.offset,
                "bytes": d.length,
                "reason": d.reason,
                "start_ns": d.start_ns,
                "end_ns": d.end_ns,
                "topics": list(d.topics),
            }
            for d in damaged
        ],
        "size_bytes": rec.size,
        "bytes_per_s": rec.size / rec.duration_s if rec.duration_s > 0 else None,
        "id": member.id,
        "kind": member.kind,
        "source": {"id": member.source_id, "name": member.source_name, "how": member.how}
        if member.kind != lineage.RECORDING
        else None,
        "trial": {"subject": subject, "condition": condition, "trial": trial},
        "start": when(rec.start_ns) if rec.start_ns is not None else None,
        "end": when(rec.end_ns) if rec.end_ns is not None else None,
        "duration_s": rec.duration_s,
        "unix_offset_ns": rec.unix_offset_ns,
        "topics": topics,
        "gaps": gaps,
        "late": late,
        "stale_orientation_frames": (flags or {}).get(STALE_ORIENTATION, 0),
        "labels": [
            {
                **when(t),
                "mode": mode,
                "source": source,
                "in_reference": (t, mode, source) in in_force,
            }
            for t, mode, source in labels
        ],
        "events": events,
        "markers": [{**when(t), "note": note} for t, note in sorted(markers)],
        "metadata": T.jsonable(rec.metadata),
        "attachments": dict(rec.attachment_sizes),
    }
