"""`walkcap eval gait`: the thigh IMU's gait events against the simulator's

    walkcap eval gait FILE.mcap|DIR ... [--tolerance-ms 60] [--recorded] [--json]

For simulated recordings (`walkcap synth --format recording`, mock sessions): the
detector (inference.gait) runs again on each file's /imu and its heel contacts and toe
offs are matched one-to-one with /sim/gait's within the tolerance. It prints, per
condition and over all, the share of the true events detected (recall) and of the
detections that are true (precision), the timing (detected - true: median, 95th
percentile of its size) and the heel contacts detected per terrain under the foot.
`--recorded` judges the /gait each file holds instead (the detector of the session or
replay that wrote it). Registered by tui/commands/eval.py.
"""

from __future__ import annotations

import json
import sys

from tui.commands import positive

HELP = "the thigh IMU's gait events against the simulator's (simulated recordings)"
TOLERANCE_MS = 60.0
TARGET = 0.98  # issue 52: heel contacts detected, and detections true


def add_arguments(parser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE.mcap", help="recordings, or folders")
    parser.add_argument(
        "--tolerance-ms",
        type=positive("MS", maximum=1000),
        default=TOLERANCE_MS,
        metavar="MS",
        help=f"a detection this close to a true event is that event (default {TOLERANCE_MS:g})",
    )
    parser.add_argument(
        "--recorded",
        action="store_true",
        help="judge the /gait the files hold instead of running the detector again",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")


def run(args, config) -> int:
    from capture.corpus.gait import gait_evaluation, totals
    from capture.corpus.selection import select
    from capture.errors import CaptureError

    corpus = select(args.files)
    if not corpus.chosen:
        raise corpus.nothing_left("no recordings to evaluate")
    for line in corpus.report_lines():
        print(line, file=sys.stderr)
    results = []
    for path in corpus.files:
        try:
            results.append(gait_evaluation(path, args.tolerance_ms, args.recorded))
        except CaptureError as e:
            print(f"left out: {e}", file=sys.stderr)
    if not results:
        raise CaptureError("no recording with the simulator's gait events (/sim/gait)")
    groups = totals(results)
    if args.json:
        print(json.dumps(_json(results, groups, args), indent=2))
    else:
        print(_text(groups, len(results), args))
    return 0


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _timing(score) -> str:
    import numpy as np

    e = np.asarray(score.errors_ms)
    if not len(e):
        return "-"
    return f"median {np.median(e):+.1f} ms, |error| p95 {np.percentile(np.abs(e), 95):.1f} ms"


def _text(groups: dict, files: int, args) -> str:
    source = "recorded /gait" if args.recorded else "the detector run again on /imu"
    lines = [
        f"gait events of {files} recording(s): {source} against /sim/gait, "
        f"within {args.tolerance_ms:g} ms"
    ]
    for group, g in sorted(groups.items(), key=lambda kv: (kv[0] == "all", kv[0])):
        lines.append("")
        lines.append(f"{group}")
        for event, s in g["scores"].items():
            lines.append(
                f"  {event:<13} true {s.true:5d}  detected {s.detected:5d}  matched "
                f"{s.matched:5d}  recall {_pct(s.recall):>7}  precision {_pct(s.precision):>7}"
                f"  {_timing(s)}"
            )
        modes = "  ".join(
            f"{m} {hit}/{n}" for m, (n, hit) in sorted(g["heel_contacts_by_mode"].items())
        )
        lines.append(f"  heel contacts detected by terrain: {modes}")
        hc = g["scores"].get("heel_contact")
        if hc is not None and hc.recall is not None and hc.precision is not None:
            ok = hc.recall >= TARGET and hc.precision >= TARGET
            lines.append(
                f"  heel contacts: {_pct(hc.recall)} detected, {_pct(hc.precision)} of the "
                f"detections true (target >= {100 * TARGET:.0f} % each: "
                f"{'met' if ok else 'NOT met'})"
            )
    return "\n".join(lines)


def _score_json(s) -> dict:
    import numpy as np

    e = np.asarray(s.errors_ms)
    return {
        "true": s.true,
        "detected": s.detected,
        "matched": s.matched,
        "recall": s.recall,
        "precision": s.precision,
        "error_ms_median": float(np.median(e)) if len(e) else None,
        "abs_error_ms_p95": float(np.percentile(np.abs(e), 95)) if len(e) else None,
    }


def _json(results: list[dict], groups: dict, args) -> dict:
    def group_json(g: dict) -> dict:
        return {
            "scores": {event: _score_json(s) for event, s in g["scores"].items()},
            "heel_contacts_by_mode": {
                m: {"true": n, "detected": hit}
                for m, (n, hit) in g["heel_contacts_by_mode"].items()
            },
        }

    return {
        "tolerance_ms": args.tolerance_ms,
        "recorded": bool(args.recorded),
        "groups": {name: group_json(g) for name, g in groups.items()},
        "files": [
            {"file": r["file"], "condition": r["condition"], **group_json(r)} for r in results
        ],
    }
