"""`walkcap share`: copies of recordings a study can share, personal fields reduced

    walkcap share recordings/ -o shared/ --secret-file study.secret
    walkcap share S01_indoor_t01_20261122-101500.mcap -o shared/ --body coarsen --shift-days -400

One file per trial (as export picks them), named <subject>_<condition>_t<NN>.mcap: sensor,
label and decision messages byte for byte; notes, operator and marker text, body data and
dates as the [share] section and the flags say (capture.corpus.share,
capture.recording.personal). `walkcap info` on a copy says what was removed.
"""

from __future__ import annotations

import sys

HELP = "copies of recordings to share: notes, operator, marker text, body data and dates reduced"


def add_arguments(parser) -> None:
    parser.add_argument(
        "files", nargs="+", metavar="FILE|DIR", help="recordings, or folders of them"
    )
    parser.add_argument(
        "-o", "--out", metavar="DIR", required=True, help="folder the shared copies go into"
    )
    text = ("drop", "replace", "keep")
    parser.add_argument("--notes", choices=text, help="the form's Notes (default: [share] notes)")
    parser.add_argument("--operator", choices=text, help="the operator (default: [share] operator)")
    parser.add_argument(
        "--markers", choices=text, help="a marker's typed note (default: [share] markers)"
    )
    parser.add_argument(
        "--body",
        choices=("keep", "coarsen", "drop"),
        help="age, height, weight, residual limb (default: [share] body)",
    )
    parser.add_argument("--sex", choices=("keep", "drop"), help="default: [share] sex")
    parser.add_argument(
        "--amputation",
        choices=("keep", "drop"),
        help="amputee and side (default: [share] amputation)",
    )
    parser.add_argument(
        "--dates",
        choices=("subject", "study", "keep"),
        help="one date offset per subject, one per study, or the real dates (default: "
        "[share] dates)",
    )
    parser.add_argument(
        "--shift-days",
        type=int,
        metavar="N",
        help="move every date by N days (negative: back) instead of the secret's offsets",
    )
    parser.add_argument(
        "--secret-file",
        metavar="PATH",
        help="a file holding the study's secret the date offsets derive from "
        "(default: [share] secret)",
    )
    parser.add_argument("--json", action="store_true", help="print what was written as JSON")


def rules_from(args, config):
    """The ShareRules of the [share] section with the flags given on top, checked."""
    from capture.errors import CaptureError
    from capture.recording.personal import RulesError, ShareRules

    section = config.share
    secret = section.secret
    if args.secret_file:
        try:
            with open(args.secret_file, encoding="utf-8") as f:
                secret = f.read().strip()
        except OSError as e:
            raise CaptureError(f"--secret-file {args.secret_file}: {e.strerror}") from None
        if not secret:
            raise CaptureError(f"--secret-file {args.secret_file}: the file is empty")
    rules = ShareRules(
        notes=args.notes or section.notes,
        operator=args.operator or section.operator,
        markers=args.markers or section.markers,
        replacement=section.replacement,
        body=args.body or section.body,
        sex=args.sex or section.sex,
        amputation=args.amputation or section.amputation,
        dates=args.dates or section.dates,
        secret=secret,
        shift_days=args.shift_days,
        max_shift_days=section.max_shift_days,
    )
    try:
        return rules.check()
    except RulesError as e:
        raise CaptureError(str(e)) from None


def run(args, config) -> int:
    import json

    from capture.corpus.share import share

    rules = rules_from(args, config)
    shared, corpus = share(args.files, args.out, rules)
    for line in corpus.report_lines():
        print(line, file=sys.stderr)
    if args.json:
        print(
            json.dumps(
                {
                    "written": [
                        {"source": str(s.source), "file": str(s.path), "removed": s.removed}
                        for s in shared
                    ],
                    "left_out": [{"file": str(p), "why": why} for p, why in corpus.left_out],
                },
                indent=2,
            )
        )
        return 0
    for s in shared:
        print(f"wrote {s.path} (from {s.source.name}): {'; '.join(s.removed) or 'nothing removed'}")
    return 0
