"""`walkcap info`: describe a recording: topics, counts, rates, gaps, metadata"""

from __future__ import annotations

import datetime as dt
import json

from devices import clock
from tui.commands import add_recordings_argument

HELP = "describe a recording: topics, counts, rates, gaps, metadata"


def add_arguments(parser) -> None:
    add_recordings_argument(parser, "MCAP recording(s), or folders of them")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print JSON (one object per file, in a list) with typed metadata",
    )


def files(paths: list[str]) -> list:
    """The files given, and the .mcap files in the folders given (and their subfolders)."""
    from pathlib import Path

    from capture.corpus.selection import recording_files

    out: list = []
    for p in paths:
        out += recording_files([p]) if Path(p).is_dir() else [p]
    return out


def run(args, config) -> int:
    from capture.recording.reader import open_recording
    from capture.recording.summary import summary

    # one file at a time, printed as soon as it is read: a folder of hundreds of trials
    # costs the memory of one
    if args.json:
        print("[", end="")
        for i, path in enumerate(files(args.files)):
            text = json.dumps(summary(open_recording(path)).to_json(), indent=2)
            print(("," if i else "") + "\n  " + text.replace("\n", "\n  "), end="", flush=True)
        print("\n]" if args.files else "]")
        return 0
    for i, path in enumerate(files(args.files)):
        if i:
            print()
        print("\n".join(describe(summary(open_recording(path)))), flush=True)
    return 0


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def _wall(s, t_ns: int) -> str:
    """Clock time (local, with its zone) of a session-clock time."""
    unix = s.unix_time_ns(t_ns)
    if unix is None:
        return f"{clock.seconds(t_ns):.3f} s (session clock)"
    return (
        dt.datetime.fromtimestamp(clock.seconds(unix)).astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")
    )


def describe(s) -> list[str]:
    """The recording (a capture.recording.summary.RecordingSummary) in a few readable lines."""
    from capture.recording import lineage
    from inference.preprocess import UNDECIDED

    lines = [str(s.path)]
    if s.damaged:
        lines.append(
            f"  state       damaged: {len(s.damaged)} region(s), "
            f"{sum(d.length for d in s.damaged if d.lost)} bytes unreadable; "
            f"`walkcap recover {s.path}` copies every intact message"
        )
        for d in s.damaged:
            lines.append(f"    damaged   {d.describe(s.start_ns)}")
    elif s.complete:
        lines.append("  state       complete")
    else:
        lines.append(
            f"  state       unfinished ({s.reason}): readable here; "
            f"`walkcap recover {s.path}` writes an indexed copy"
        )
    rate = f" ({_size(s.size_bytes / s.duration_s)}/s)" if s.duration_s > 0 else ""
    lines.append(f"  size        {_size(s.size_bytes)}{rate}")
    member = s.member
    lines.append(f"  trial       {member.trial_name}; id {member.id}")
    if member.kind != lineage.RECORDING:
        lines.append(
            f"  derived     {member.kind} of {member.source_name or '?'}"
            + (f" (id {member.source_id})" if member.source_id else "")
            + (f": {member.how}" if member.how else "")
        )
    sharing = s.meta.sharing
    if sharing:  # a copy made for sharing: what it lacks (corpus.share)
        removed = sharing.removed or []
        lines.append(f"  shared      removed: {'; '.join(removed) or 'nothing'}")
    if s.start_ns is not None:
        lines.append(
            f"  time        {_wall(s, s.start_ns)} -> {_wall(s, s.end_ns)}, {s.duration_s:.1f} s"
        )
        lines.append(
            f"  session     {clock.seconds(s.start_ns):.3f} -> {clock.seconds(s.end_ns):.3f} s "
            "(session clock: the message times; + unix_offset_ns = Unix time)"
        )
    lines.append("  topics      messages    rate  schema" if s.topics else "  topics      none")
    for t in s.topics:
        hz = f"{t.rate_hz:6.1f} Hz" if t.rate_hz is not None else "      - "
        lines.append(f"    {t.topic:<22} {t.messages:7d} {hz}  {t.schema}")
    gaps, late = [], []
    if s.losses is None:
        gaps.append("not counted (the file is damaged; count them on its recovered copy)")
    for topic, loss in (s.losses or {}).items():
        if loss.gaps:
            g = max(loss.gaps, key=lambda g: g.length_s)
            at = s.at_s(g.start_ns) or 0.0
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
    if s.frame_flags is not None:
        empty = ", ".join(
            f"{k} {v}" for k, v in sorted(s.frame_flags.items()) if k not in UNDECIDED
        )
        lines.append(
            f"  frames      {s.processed_frames} processed; stale orientation "
            f"{s.stale_orientation_frames}, bad orientation {s.bad_orientation_frames} "
            "(no image, no decision)" + (f"; no image: {empty}" if empty else "")
        )
    if s.labels:
        # the modes as they stand: an undone change (and the undo) is no mode of the trial
        sequence = " ".join(mode or "-" for _, mode, _ in s.reference)
        undone = f" ({s.undos} undo(s) applied: what they took back is left out)" if s.undos else ""
        lines.append(f"  labels      {len(s.labels)} changes{undone}: {_clip(sequence)}")
    if s.events:
        lines.append("  events      " + ", ".join(f"{k} {v}" for k, v in sorted(s.events.items())))
    for t, note in s.markers:
        at = s.at_s(t) if s.start_ns is not None else clock.seconds(t)
        lines.append(f"  marker      +{at:.1f} s  {_clip(note or 'marker')}")
    lines.append("  metadata")
    for name, values in s.metadata.items():
        if name == "recording":
            values = {k: v for k, v in values.items() if k != "topics"}
        text = ", ".join(f"{k}={_short(v)}" for k, v in values.items() if v not in ("", None))
        lines.append(f"    {name:<11} {text}")
    if s.attachments:
        lines.append(
            "  attachments "
            + ", ".join(f"{name} ({_size(n)})" for name, n in s.attachments.items())
        )
    return lines


def _short(value, width: int = 60) -> str:
    if isinstance(value, (dict, list)):
        return _clip(json.dumps(value, separators=(",", ":")), width)
    return _clip(str(value), width)


def _clip(text: str, width: int = 100) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."
