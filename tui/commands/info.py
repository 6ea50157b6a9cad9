"""`walkcap info`: describe a recording: topics, counts, rates, gaps, metadata"""

from __future__ import annotations

import datetime as dt
import json

HELP = "describe a recording: topics, counts, rates, gaps, metadata"

GAP_TOPICS = ("/camera/depth", "/imu")  # the sensor streams; the rest derive from them


def add_arguments(parser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE", help="MCAP recording(s)")


def run(args, config) -> int:
    from capture.reader import open_recording

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
    offset = rec.unix_offset_ns
    if offset is None:
        return f"{t_ns * 1e-9:.3f} s (session clock)"
    return dt.datetime.fromtimestamp((t_ns + offset) * 1e-9).strftime("%Y-%m-%d %H:%M:%S")


def describe(rec) -> list[str]:
    """The recording in a few readable lines."""
    from capture import topics as T
    from capture.errors import CaptureError
    from capture.reader import find_gaps
    from capture.recovery import check

    lines = [str(rec.path)]
    damaged = check(rec.path).damaged  # every chunk's CRC, finished file or not
    if damaged:
        lines.append(
            f"  state       damaged: {len(damaged)} region(s), "
            f"{sum(d.length for d in damaged)} bytes unreadable; "
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
    if rec.start_ns is not None:
        lines.append(
            f"  time        {_wall(rec, rec.start_ns)} -> {_wall(rec, rec.end_ns)}, "
            f"{rec.duration_s:.1f} s"
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
    gaps = []
    periods = recorded_periods(rec.metadata)
    for topic in GAP_TOPICS:
        if topic in times:
            found = find_gaps(times[topic], period_s=periods.get(topic))
            if found:
                start, longest = max(found, key=lambda g: g[1])
                at = (start - rec.start_ns) * 1e-9 if rec.start_ns is not None else 0.0
                gaps.append(f"{topic} {len(found)} (longest {longest:.2f} s at +{at:.1f} s)")
            else:
                gaps.append(f"{topic} none")
    if gaps:
        lines.append("  gaps        " + "; ".join(gaps))
    small = [t for t in (T.LABELS, T.EVENTS) if t in rec.topics]
    labels, kinds = [], {}
    try:
        for m in rec.messages(small):
            if m.topic == T.LABELS:
                labels.append((m.data["time_ns"], m.data["mode"] or "-"))
            else:
                kinds[m.data["kind"]] = kinds.get(m.data["kind"], 0) + 1
    except CaptureError:  # damaged: the labels and events before the damage are listed
        if not damaged:
            raise
    if labels:
        sequence = " ".join(mode for _, mode in sorted(labels))
        lines.append(f"  labels      {len(labels)} changes: {_clip(sequence)}")
    if kinds:
        lines.append("  events      " + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))
    lines.append("  metadata")
    for name, values in rec.metadata.items():
        if name == "recording":
            values = {k: v for k, v in values.items() if k != "topics"}
        text = ", ".join(f"{k}={_short(v)}" for k, v in values.items() if v != "")
        lines.append(f"    {name:<11} {text}")
    if rec.attachment_sizes:
        lines.append(
            "  attachments "
            + ", ".join(f"{name} ({_size(n)})" for name, n in rec.attachment_sizes.items())
        )
    return lines


def recorded_periods(metadata: dict) -> dict[str, float]:
    """Each sensor topic's configured period from the file's metadata (the live alarms
    count gaps against it); a topic without one falls back on its median interval."""
    devices = metadata.get("devices", {})
    out = {}
    for topic, key in (("/camera/depth", "camera_fps"), ("/imu", "imu_rate_hz")):
        try:
            rate = float(devices.get(key, ""))
        except ValueError:
            continue
        if rate > 0:
            out[topic] = 1.0 / rate
    return out


def _short(value: str, width: int = 60) -> str:
    try:
        parsed = json.loads(value)
        if isinstance(parsed, (dict, list)):
            value = json.dumps(parsed, separators=(",", ":"))
    except ValueError:
        pass
    return _clip(value, width)


def _clip(text: str, width: int = 100) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."
