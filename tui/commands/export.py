"""`walkcap export`: recordings as tables for analysis (Parquet, CSV, MATLAB .mat), or a
BIDS-Motion dataset to publish

    walkcap export recordings/ --format parquet --out tables/
    walkcap export S01_indoor_t01.mcap --format mat --out tables/
    walkcap export recordings/ --format bids -o dataset/      (capture.corpus.bids)

One file per trial (a corrected copy stands for its trial, a recovered copy for its
unfinished original, replays only with --replays); the files left out are listed, why.
Tables: frames, imu, labels, events, trials (capture.corpus.export).
"""

from __future__ import annotations

import sys

from capture.errors import CaptureError
from tui.commands import add_cluster_argument, add_recordings_argument

HELP = "recordings as tables for analysis (Parquet, CSV, MATLAB .mat) or a BIDS dataset"


def add_arguments(parser) -> None:
    add_recordings_argument(parser)
    parser.add_argument(
        "--format",
        choices=("parquet", "csv", "mat", "bids"),
        default="parquet",
        help="parquet (pandas, Arrow), csv, mat: one walkcap.mat with a struct per "
        "table (MATLAB), or bids: a BIDS-Motion dataset, created or added to "
        "(default: parquet)",
    )
    parser.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        required=True,
        help="folder to write the tables into (bids: the dataset's folder)",
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
    bids = parser.add_argument_group("bids (the [study] section gives the defaults)")
    bids.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a trial already in the dataset (default: skip it)",
    )
    bids.add_argument("--study-name", metavar="NAME", help="the dataset's name ([study] name)")
    bids.add_argument(
        "--author",
        action="append",
        metavar="NAME",
        help="an author of the dataset, repeatable ([study] authors)",
    )
    bids.add_argument(
        "--license", metavar="SPDX", help="the data's license, e.g. CC0-1.0 ([study] license)"
    )
    bids.add_argument(
        "--deidentify",
        action="store_true",
        help="by the [share] rules (walkcap share's): dates moved by whole days, marker "
        "notes and body data as the rules say, the originals left out of sourcedata/",
    )
    bids.add_argument(
        "--shift-days",
        type=int,
        metavar="N",
        help="with --deidentify: move every date by N days (negative: back) instead of the "
        "offsets derived from the study's secret",
    )
    bids.add_argument(
        "--secret-file",
        metavar="PATH",
        help="with --deidentify: a file holding the study's secret (default: [share] secret)",
    )
    add_cluster_argument(parser, "the reading of each recording")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print what was written as JSON")


def run(args, config) -> int:
    import json

    from capture.corpus import export

    if args.format == "bids":
        return _bids(args, config)
    bids_only = [
        f
        for f, on in (
            ("--overwrite", args.overwrite),
            ("--deidentify", args.deidentify),
            ("--study-name", args.study_name),
            ("--author", args.author),
            ("--license", args.license),
            ("--shift-days", args.shift_days is not None),
            ("--secret-file", args.secret_file),
        )
        if on
    ]
    if bids_only:
        raise CaptureError(f"{bids_only[0]} goes with --format bids")
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


def _bids(args, config) -> int:
    import argparse
    import dataclasses
    import json

    from capture.corpus import bids

    if args.every_file or args.cluster:
        raise CaptureError(
            "--format bids takes one file per trial, here: no --every-file, --cluster"
        )
    study = dataclasses.replace(config.study)
    if args.study_name is not None:
        study.name = args.study_name
    if args.author:
        study.authors = list(args.author)
    if args.license is not None:
        study.license = args.license
    share = None
    if args.deidentify:
        from tui.commands import share as share_command

        # the [share] section as `walkcap share` reads it, with no rule flag on top
        given = argparse.Namespace(
            **dict.fromkeys(("notes", "operator", "markers", "body", "sex", "amputation")),
            dates=None,
            shift_days=args.shift_days,
            secret_file=args.secret_file,
        )
        share = share_command.rules_from(given, config)
    elif args.shift_days is not None or args.secret_file:
        raise CaptureError("--shift-days and --secret-file go with --deidentify")
    result = bids.export(
        args.files, args.out, study, overwrite=args.overwrite, replays=args.replays, share=share
    )
    for line in result.corpus.report_lines():
        print(line, file=sys.stderr)
    unset = [k for k in bids.RECOMMENDED_STUDY_KEYS if not getattr(study, k)]
    if unset:
        print(
            f"note: [study] {', '.join(unset)} not set: BIDS recommends them, the validator "
            "warns without them (flags: --author, --license, --study-name)",
            file=sys.stderr,
        )
    if args.json:
        print(
            json.dumps(
                {
                    "dataset": str(args.out),
                    "written": [str(t.path) for t in result.written],
                    "skipped": [{"file": str(t.path), "why": why} for t, why in result.skipped],
                    "left_out": [{"file": str(p), "why": why} for p, why in result.corpus.left_out],
                },
                indent=2,
            )
        )
        return 0
    for t in result.written:
        print(f"{t.stem}: {t.path.name}")
    for t, why in result.skipped:
        print(f"{t.stem}: skipped, {why}")
    print(f"{args.out}: {len(result.written)} trial(s) written, {len(result.skipped)} skipped")
    return 0
