"""`walkcap export`: recordings as tables for analysis (Parquet, CSV, MATLAB .mat)

    walkcap export recordings/ --format parquet --out tables/
    walkcap export S01_indoor_t01.mcap --format mat --out tables/

One file per trial (a corrected copy stands for its trial, a recovered copy for its
unfinished original, replays only with --replays); the files left out are listed, why.
Tables: frames, imu, labels, events, trials (capture.corpus.export).
"""

from __future__ import annotations

import sys

from tui.commands import add_cluster_argument

HELP = "recordings as tables for analysis: Parquet, CSV or MATLAB .mat"


def add_arguments(parser) -> None:
    parser.add_argument(
        "files", nargs="+", metavar="FILE|DIR", help="recordings, or folders of them"
    )
    parser.add_argument(
        "--format",
        choices=("parquet", "csv", "mat"),
        default="parquet",
        help="parquet (pandas, Arrow), csv, or mat: one walkcap.mat with a struct per "
        "table (MATLAB) (default: parquet)",
    )
    parser.add_argument(
        "-o", "--out", metavar="DIR", required=True, help="folder to write the tables into"
    )
    parser.add_argument(
        "--replays",
        action="store_true",
        help="the newest replay of each trial stands for it (another model's output)",
    )
    parser.add_argument(
        "--every-file",
        action="store_true",
        help="every file given, derived copies included, without picking one per trial",
    )
    add_cluster_argument(parser, "the reading of each recording")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print what was written as JSON")


def run(args, config) -> int:
    import json

    from capture.corpus import export

    # trial by trial through a spool: the tables of hundreds of trials are never all in memory
    written, rows, corpus = export.write_corpus(
        args.files,
        args.out,
        args.format,
        replays=args.replays,
        every_file=args.every_file,
        progress=not args.quiet and not args.json,
        cluster=args.cluster,
    )
    for line in corpus.report_lines():
        print(line, file=sys.stderr)
    if args.json:
        print(
            json.dumps(
                {
                    "written": [str(p) for p in written],
                    "rows": rows,
                    "trials": [str(p) for p in corpus.files] if corpus.chosen else None,
                    "left_out": [{"file": str(p), "why": why} for p, why in corpus.left_out],
                },
                indent=2,
            )
        )
        return 0
    print(
        f"{rows['trials']} file(s): "
        + ", ".join(f"{rows[n]} {n}" for n in ("frames", "imu", "labels", "events"))
    )
    for p in written:
        print(f"wrote {p}")
    return 0
