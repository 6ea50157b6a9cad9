"""`walkcap eval`: evaluate classifiers and fusion on score files or recordings

    walkcap eval scores FILE.csv ... [--window 5] [--vote-delay 1] [--json]
    walkcap eval recordings FILE.mcap ... [--sweep-delay [N]] [--plot DIR] [--json]
    walkcap eval model ...            (the CNN on unseen synthetic sessions; eval_model.py)
    walkcap eval gait FILE.mcap ...   (the IMU's gait events against the simulator's; eval_gait.py)

Accuracies are per trial (file), then mean +- SD across trials, as in the paper, against
the `terrain` reference (what the images show) unless `--reference locomotion` asks for the
live keys; the transition metrics (spurious switches, missed changes, switch delay, lead
time) against each reference a trial has.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from inference.config import FusionConfig
from inference.fusion import METHOD_TABLE, METHODS
from tui.commands import add_cluster_argument, count, eval_gait, eval_model, positive

HELP = "evaluate classifiers and fusion on score files or recordings"

DEFAULT_METHODS = ",".join(m.name for m in METHOD_TABLE if m.default)
_CUE_METHODS = [m.name for m in METHOD_TABLE if m.cues]  # recordings carry their cues
RECORDING_METHODS = ",".join([DEFAULT_METHODS, *_CUE_METHODS])
SWEEP_DEFAULT = 6  # frames; the paper's trade-off figure reaches 6
SWEEP_MAX = 100  # frames: several seconds of delay, beyond any use for a prosthesis


def _methods(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown method {', '.join(unknown) or '(none)'} (known: {', '.join(METHODS)})"
        )
    return list(dict.fromkeys(names))


def _methods_help() -> str:
    cues = ", ".join(_CUE_METHODS[:-1]) + " and " + _CUE_METHODS[-1]
    each = "; ".join(f"{m.name}: {m.doc.replace('`', '')}" for m in METHOD_TABLE)
    return (
        f"comma-separated methods (default: {DEFAULT_METHODS}, and {cues} for recordings). {each}"
    )


# the [fusion] frame counts a run may set: key, its smallest value, what it counts
_FUSION_COUNTS = (
    ("window", 1, "l_w, the HMM's smoothing window in frames"),
    ("vote_delay", 0, "l_v, voting half-window in frames"),
    ("lag", 0, "lag of the fixed-lag smoother in frames"),
)


def _common_arguments(p: argparse.ArgumentParser) -> None:
    defaults = FusionConfig()
    for key, smallest, what in _FUSION_COUNTS:
        p.add_argument(
            "--" + key.replace("_", "-"),
            type=count(smallest),
            metavar="N",
            help=f"{what} (default: [fusion] {key}, {getattr(defaults, key)})",
        )
    p.add_argument(
        "--methods",
        type=_methods,
        default=None,
        metavar="LIST",
        help=_methods_help(),
    )
    p.add_argument(
        "--transition",
        choices=("config", "paper", "estimated"),
        default="config",
        help="transition matrix: [fusion] transition (default: the authors'), the "
        "authors', or counted from the other files' labels (leave one out)",
    )
    p.add_argument(
        "--sweep-delay",
        type=count(0, SWEEP_MAX),
        nargs="?",
        const=SWEEP_DEFAULT,
        metavar="N",
        help=f"also accuracy against 0..N delayed frames (default N: {SWEEP_DEFAULT})",
    )
    p.add_argument(
        "--plot",
        metavar="DIR",
        help="write the paper's figures into DIR, each as vector PDF and 300-dpi PNG: "
        "accuracy per subject, against delay (with --sweep-delay), sequential decisions "
        "and probability traces of every trial, confusion matrices per condition",
    )
    p.add_argument(
        "--plot-trials",
        type=lambda text: [t.strip() for t in text.split(",") if t.strip()],
        metavar="LIST",
        help="with --plot: the decision and probability figures only for trials whose "
        "file name or title (subject, condition, trial) contains one of these "
        "comma-separated words (default: every trial)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    verbs = parser.add_subparsers(dest="eval_command", metavar="VERB", required=True)

    p = verbs.add_parser(
        "scores",
        help="any classifier's per-frame scores from CSV files",
        description="Evaluate per-frame scores: each CSV has the header "
        "LG,US,DS,UR,DR,label and one row per frame in capture order; label is the terrain "
        "each image shows. Optional columns after it, in this order: locomotion, the "
        "subject's mode keyed live (adds the lead time); heel_contact and toe_off, 1 on the "
        "first frame at or after each gait event of the instrumented leg (adds the per-step "
        "figures, and feeds steady+steps).",
    )
    p.add_argument("files", nargs="+", metavar="FILE.csv", help="score files, one per trial")
    p.add_argument(
        "--fps",
        type=positive("HZ", maximum=1000),
        default=15.0,
        metavar="HZ",
        help="frames a second, for times (default: 15, the paper's camera)",
    )
    _common_arguments(p)

    p = verbs.add_parser(
        "recordings",
        help="the recorded CNN outputs of MCAP recordings",
        description="Evaluate recordings, grouped by subject and condition: accuracy "
        "against the terrain reference (what each image shows: the simulator's truth or "
        "labels made in replay --tui), switches against it and lead time against the "
        "subject's mode keyed live (the locomotion reference).",
    )
    p.add_argument("files", nargs="+", metavar="FILE.mcap", help="recordings, or folders of them")
    p.add_argument(
        "--reference",
        choices=("terrain", "locomotion"),
        default="terrain",
        help="what accuracy is scored against: terrain, what each image shows (the "
        "paper's; default), or locomotion, the live keys, which change about a second "
        "after the terrain ahead (asked for explicitly, never chosen for you)",
    )
    p.add_argument(
        "--replays",
        action="store_true",
        help="evaluate the newest replay of each trial instead of its recording "
        "(another model's output on the same trial)",
    )
    add_cluster_argument(p, "the reading of each recording")
    _common_arguments(p)

    p = verbs.add_parser("model", help=eval_model.HELP, description=eval_model.HELP)
    eval_model.add_arguments(p)

    p = verbs.add_parser("gait", help=eval_gait.HELP, description=eval_gait.HELP)
    eval_gait.add_arguments(p)


def run(args, config) -> int:
    if args.eval_command == "model":
        return eval_model.run(args, config)
    if args.eval_command == "gait":
        return eval_gait.run(args, config)

    from dataclasses import replace

    from inference import evaluation as ev
    from inference.errors import InferenceError
    from inference.fusion_design import PAPER_TRANSITION, validate_transition

    window = args.window if args.window is not None else config.fusion.window
    vote_delay = args.vote_delay if args.vote_delay is not None else config.fusion.vote_delay
    if window < 1 or vote_delay < 0:
        raise InferenceError(
            f"fusion.window must be >= 1 and fusion.vote_delay >= 0 (got {window}, {vote_delay})"
        )
    transition = (
        PAPER_TRANSITION
        if args.transition == "paper"
        else validate_transition(config.fusion.transition, "fusion.transition")
    )
    params = replace(
        config.fusion,
        window=window,
        vote_delay=vote_delay,
        transition=transition,
        lag=args.lag if args.lag is not None else config.fusion.lag,
    )

    if args.methods is None:
        default = RECORDING_METHODS if args.eval_command == "recordings" else DEFAULT_METHODS
        args.methods = _methods(default)
    # What needs every trial's frames at once: the plots, the delay sweep, transitions
    # estimated from the other trials. Otherwise recordings are read and evaluated one at
    # a time, each kept as its figures alone.
    whole = args.plot or args.sweep_delay is not None or args.transition == "estimated"
    if args.eval_command == "scores":
        trials = [ev.read_scores(path, args.fps) for path in args.files]
    else:
        files = _recordings(args.files, args.replays)
        if whole:
            trials = _trials(files, args.reference, args.cluster)
        else:
            trials = None
            results = _results(files, args.reference, args.cluster, args.methods, params)
    if trials is not None:
        per_trial = params
        if args.transition == "estimated":
            transitions = ev.leave_one_out_transitions(trials)
            per_trial = [replace(params, transition=t) for t in transitions]
        results = ev.evaluate(trials, args.methods, per_trial)
    sweep = (
        ev.delay_sweep(trials, args.methods, args.sweep_delay, per_trial)
        if args.sweep_delay is not None
        else None
    )
    grouped = args.eval_command == "recordings"
    data = ev.report(results, args.methods, params, sweep, grouped)
    data["parameters"]["transition"] = args.transition
    if args.plot:
        data["plots"] = [
            str(p)
            for p in ev.write_plots(
                results, args.plot, args.methods, params, sweep, args.plot_trials
            )
        ]
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print(format_report(data, args.methods))
    return 0


# ---------------------------------------------------------------------------------------
# text output


def _title(method: str) -> str:
    from inference.evaluation import TITLES

    return TITLES.get(method, method)


def _pct(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.2f}"


def _table(headers: list[str], rows: list[list[str]], left: int = 1) -> list[str]:
    """Plain aligned columns: the first `left` columns left-aligned, the rest right."""
    widths = [max(len(str(r[i])) for r in [headers, *rows]) for i in range(len(headers))]

    def line(cells) -> str:
        return "  ".join(
            str(c).ljust(w) if i < left else str(c).rjust(w)
            for i, (c, w) in enumerate(zip(cells, widths))
        ).rstrip()

    return [line(headers), *(line(r) for r in rows)]


def format_report(data: dict, methods: list[str]) -> str:
    p = data["parameters"]
    reference = data["accuracy_reference"]
    reference = reference if isinstance(reference, str) else " / ".join(reference)
    out = [
        f"{len(data['files'])} file(s); l_w = {p['window']}, l_v = {p['vote_delay']}, "
        f"transition: {p['transition']}; accuracy in % against the {reference} reference",
        "",
    ]
    titles = [_title(m) for m in methods]
    rows = [
        [f["path"], str(f["frames"]), *(_pct(f["accuracy"][m]) for m in methods)]
        for f in data["files"]
    ]
    rows.append(["mean", "", *(_pct(data["mean"][m]) for m in methods)])
    rows.append(["SD", "", *(_pct(data["sd"][m]) for m in methods)])
    rows.append(["delay (frames)", "", *(str(data["delay_frames"][m]) for m in methods)])
    out += _table(["file", "frames", *titles], rows)

    if "groups" in data:
        out.append("")
        rows = []
        for g in data["groups"]:
            rows.append(
                [
                    g["condition"] or "-",
                    g["subject"],
                    str(g["trials"]),
                    *(_mean_sd(g, m) for m in methods),
                ]
            )
        for c in data["conditions"]:
            rows.append(
                [c["condition"] or "-", "all", str(c["trials"]), *(_mean_sd(c, m) for m in methods)]
            )
        out += _table(["condition", "subject", "trials", *titles], rows, left=2)

    out += _format_transitions(data, methods)
    out += _format_steps(data, methods)
    out += _format_errors(data, reference)

    out += _format_tests(data.get("paired_t_tests"))

    sweep = data.get("sweep")
    if sweep:
        out += ["", "accuracy (%) against delayed frames (mean over files):"]
        rows = [[_title(m), *(_pct(x) for x in sweep["mean"][m])] for m in methods]
        out += _table(["method", *map(str, sweep["delays"])], rows)
        out += ["", f"spurious switches a minute (against {reference}) against delayed frames:"]
        rows = [[_title(m), *(_num(x, 1) for x in sweep["spurious_per_min"][m])] for m in methods]
        out += _table(["method", *map(str, sweep["delays"])], rows)
    if data.get("plots"):
        folders = sorted({str(Path(p).parent) for p in data["plots"]})
        out += [
            "",
            f"wrote {len(data['plots'])} figure file(s) (PDF and PNG) to {', '.join(folders)}",
        ]
    return "\n".join(out)


def _format_tests(tests: dict | None) -> list[str]:
    """The paired t-tests, or why there are none."""
    if not tests:
        return []
    n = tests["trials"]
    if tests["too_few"]:
        return [
            "",
            f"paired t-tests: n={n} trial(s): too few for a test (need >= {tests['min_trials']})",
        ]
    if not tests["tests"]:
        return []
    out = [
        "",
        f"paired t-tests over {n} trials (p Holm-corrected over {len(tests['tests'])} "
        "comparisons; diff: mean difference in points, d_z: diff / SD of the differences):",
    ]
    rows = [
        [
            f"{_title(t['a'])} vs {_title(t['b'])}",
            f"diff {_pct(t['mean_difference'])}",
            "t =       -" if t["t"] is None else f"t = {t['t']:7.3f}",
            "p = -" if t["p"] is None else f"p = {t['p']:.3g}",
            "p_Holm = -" if t["p_holm"] is None else f"p_Holm = {t['p_holm']:.3g}",
            "d_z = -" if t["d_z"] is None else f"d_z = {t['d_z']:.2f}",
        ]
        for t in tests["tests"]
    ]
    return out + ["  " + line for line in _table([""] * 6, rows, left=6)[1:]]


def _num(x: float | None, digits: int = 0) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _format_transitions(data: dict, methods: list[str]) -> list[str]:
    """Switches per method and reference, pooled over the files (and per condition)."""
    scopes = [("all", data["transitions"])]
    if len(data.get("conditions") or []) > 1:
        scopes += [(c["condition"] or "-", c["transitions"]) for c in data["conditions"]]
    out: list[str] = []
    names = list(dict.fromkeys(n for _, t in scopes for m in methods for n in t.get(m, {})))
    for name in names:
        if name == "locomotion":
            out += [
                "",
                "lead time against the locomotion reference (the subject's mode keyed live): "
                "how long before it changed the decision switched, ms; late: switched after it",
            ]
            head = ["", "method", "changes", "missed", "late", "lead median", "lead p10"]
        else:
            out += [
                "",
                f"switches against the {name} reference: spurious (a switch where the "
                f"{name} did not change) a minute, missed changes, delay from the change "
                "to the known switch",
            ]
            head = ["", "method", "changes", "missed", "spurious/min", "delay frames", "delay ms"]
        rows = []
        for scope, transitions in scopes:
            for m in methods:
                s = transitions.get(m, {}).get(name)
                if s is None:
                    continue
                if name == "locomotion":
                    tail = [str(s["late"]), _num(s["lead_ms"]["median"]), _num(s["lead_ms"]["p10"])]
                else:
                    tail = [
                        _num(s["spurious_per_min"], 1),
                        _num(s["delay_frames"]["median"], 1),
                        _num(s["delay_ms"]["median"]),
                    ]
                rows.append([scope, _title(m), str(s["changes"]), str(s["missed"]), *tail])
        out += _table(head, rows, left=2)
    return out


def _format_steps(data: dict, methods: list[str]) -> list[str]:
    """The per-step figures per method, pooled over the files (and per condition)."""
    scopes = [("all", data.get("steps") or {})]
    if len(data.get("conditions") or []) > 1:
        scopes += [(c["condition"] or "-", c.get("steps") or {}) for c in data["conditions"]]
    if not scopes[0][1]:
        return []
    any_stats = next(iter(scopes[0][1].values()))
    out = [
        "",
        f"per step (gait events: {any_stats['source']}, step modes: {any_stats['mode_source']}): "
        "errors at heel contact and at toe off in %, transition steps wrong at their heel "
        "contact (late), median lead in steps, critical errors (wrong at a heel contact more "
        "than one step from a transition) a minute",
    ]
    head = ["", "method", "heel contacts", "HC err", "TO err", "transitions", "late", "lead"]
    head.append("critical/min")
    rows = []
    for scope, steps in scopes:
        for m in methods:
            s = steps.get(m)
            if s is None:
                continue
            rows.append(
                [
                    scope,
                    _title(m),
                    str(s["heel_contacts"]),
                    _pct(s["error_rate_at_heel_contact"]),
                    _pct(s["error_rate_at_toe_off"]),
                    str(s["transition_steps"]),
                    str(s["transition_steps_late"]),
                    _num(s["lead_steps"]["median"], 1),
                    _num(s["critical_per_min"], 2),
                ]
            )
    return out + _table(head, rows, left=2)


def _format_errors(data: dict, reference: str) -> list[str]:
    """The shape of the classifier's own errors, per condition (docs/analysis.md)."""
    scopes = [("all", data.get("errors"))]
    if data.get("conditions"):
        scopes += [(c["condition"] or "-", c.get("errors")) for c in data["conditions"]]
    rows = []
    for scope, e in scopes:
        if not e or not e["frames"]:
            continue
        rows.append(
            [
                scope,
                _pct(e["error_rate"]),
                _num(e["runs_per_min"], 1),
                _pct(e["in_runs"]),
                " ".join(f"{k}:{n}" for k, n in e["run_lengths"].items()),
                _num(e["confidence_wrong_median"], 2),
                _pct(e["confident_wrong"]),
                _pct(e["near_change"]),
                f"{_pct(e['error_rate_swing'])} / {_pct(e['error_rate_stance'])}",
            ]
        )
    if not rows:
        return []
    out = [
        "",
        f"the classifier's own errors (its argmax against {reference}): error rate %, runs of "
        "wrong frames a minute, share of wrong frames in runs of 2 or more %, runs by length, "
        "median confidence when wrong, wrong at confidence >= 0.9 %, wrong within 0.5 s of a "
        "change %, error rate in swing / stance %",
    ]
    headers = ["", "errors", "runs/min", "in runs", "run lengths", "conf", "sure", "near"]
    return out + _table([*headers, "swing/stance"], rows)


def _mean_sd(entry: dict, method: str) -> str:
    mean, sd = entry["mean"][method], entry["sd"][method]
    return _pct(mean) if sd is None else f"{_pct(mean)} ± {_pct(sd)}"


def _recordings(paths: list[str], replays: bool = False) -> list[str]:
    """One file per trial from the files and folders given (capture.corpus.selection.select); the
    files left out are listed on stderr, with why."""
    import sys

    from capture.corpus.selection import select

    corpus = select(paths, replays=replays)
    if not corpus.chosen:
        raise corpus.nothing_left("no recordings to evaluate")
    for line in corpus.report_lines():
        print(line, file=sys.stderr)
    return [str(p) for p in corpus.files]


def _results(files: list[str], reference: str, address: str | None, methods, params) -> list:
    """Each recording's summarized result (capture.corpus.evaluate), here or with one Ray
    task each; in the order given, each named by its path as given."""
    from capture.corpus import jobs
    from capture.corpus.evaluate import evaluate_recording

    where = jobs.choose(address)
    tasks = [
        jobs.Task(
            Path(f).name,
            evaluate_recording,
            (jobs.task_path(where, f), reference, f, list(methods), params),
        )
        for f in files
    ]
    progress = None if address else False
    return jobs.run(tasks, where, desc="eval", unit="recording", show_progress=progress)


def _trials(files: list[str], reference: str, address: str | None) -> list:
    """One evaluation trial per recording, here or with one Ray task each; in the order
    given, each named by its path as given."""
    from capture.corpus import jobs
    from capture.corpus.trials import read_evaluation_trial

    where = jobs.choose(address)
    tasks = [
        jobs.Task(Path(f).name, read_evaluation_trial, (jobs.task_path(where, f), reference, f))
        for f in files
    ]
    # a bar on a terminal for a cluster's job; here the trials are read without one
    progress = None if address else False
    return jobs.run(tasks, where, desc="eval", unit="recording", show_progress=progress)
