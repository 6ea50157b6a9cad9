"""`walkcap recover`: rebuild a valid MCAP from a recording cut off by a crash"""

from __future__ import annotations

HELP = "rebuild a valid MCAP from a recording cut off by a crash"


def add_arguments(parser) -> None:
    parser.add_argument("file", metavar="FILE", help="the cut-off recording (kept unchanged)")
    parser.add_argument(
        "-o",
        "--out",
        metavar="FILE",
        help="the rebuilt file (default: FILE with .recovered before .mcap)",
    )
    parser.add_argument(
        "--journal",
        metavar="PATH",
        help="label journal to merge (default: FILE.journal.jsonl if present; "
        "a named journal must exist)",
    )
    parser.add_argument("--force", action="store_true", help="replace OUT if it exists")


def run(args, config) -> int:
    from capture.recording.recover import recover

    r = recover(args.file, args.out, journal=args.journal, overwrite=args.force)
    if r.complete:
        source = "complete file"
    elif r.finished:
        source = "finished file, damaged"
    else:
        source = f"{r.reason}; {r.lost_bytes} bytes after it unreadable"
    print(f"{r.source}: {source}")
    for d in r.damaged:
        print(f"{'skipped' if d.lost else 'found'} damaged {d.describe(r.first_ns)}")
    for why in r.journal_skipped:
        print(f"skipped journal {why}")
    if r.unknown_channel_messages:
        print(f"skipped {r.unknown_channel_messages} messages whose channel was in damaged bytes")
    print(
        f"wrote {r.output}: {r.messages} messages, {r.duration_s:.1f} s of sensor data, "
        f"{r.labels_added} labels and {r.events_added} markers added from the journal"
        + ("" if r.journal else " (no journal found)")
    )
    return 0 if r.salvaged else 1
