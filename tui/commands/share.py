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

from tui.commands import add_recordings_argument

HELP = "copies of recordings to share: notes, operator, marker text, body data and dates reduced"


_TEXT = ("drop", "replace", "keep")
_FIELD = ("keep", "drop")
# The ShareRules fields a flag of the same name sets: (name, choices, what it covers).
_RULES = (
    ("notes", _TEXT, "the form's Notes"),
    ("operator", _TEXT, "the operator"),
    ("markers", _TEXT, "a marker's typed note"),
    ("body", ("keep", "coarsen", "drop"), "age, height, weight, residual limb"),
    ("sex", _FIELD, "sex"),
    ("amputation", _FIELD, "amputee and side"),
    (
        "dates",
        ("subject", "study", "keep"),
        "one date offset per subject, one per study, or the real dates",
    ),
)


def add_arguments(parser) -> None:
    add_recordings_argument(parser)
    parser.add_argument(
        "-o", "--out", metavar="DIR", required=True, help="folder the shared copies go into"
    )
    for name, choices, what in _RULES:
        parser.add_argument(f"--{name}", choices=choices, help=f"{what} (default: [share] {name})")
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
    rules = ShareRules.from_config(
        section,
        **{name: getattr(args, name) for name, *_ in _RULES},
        secret=secret,
        shift_days=args.shift_days,
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
