"""`walkcap eval model`: the terrain classifier's per-frame quality on unseen sessions

    walkcap eval model [--model PATH] [--sessions N] [--preset both] [--seed S] [--frames N]
    walkcap eval model --data DIR|FILE ... [--model PATH]
    walkcap eval model --textbook [--model PATH]

Without --data it renders N fresh synthetic sessions (default 4, alternating indoor and
outdoor, seeds from 100000: never used for the bundled model's training) and prints the
per-class accuracy and confusion matrix per preset. Synthesized sessions carry the
simulator's truth, so the report also says where the errors are (error images, frames near
a mode change by what their view shows, elsewhere) and what an oracle that answers each
view's mode would score. --textbook scores the textbook set instead (inference.textbook:
the five terrains drawn by the authors' recipe, 100 images a class). Registered by
tui/commands/eval.py.
"""

from __future__ import annotations

import json

from tui.commands import add_preset_argument, count

HELP = "the CNN's per-frame accuracy on unseen synthetic sessions"
UNSEEN_SEED = 100_000  # synthetic training sets use small seeds
_positive = count(1)


def add_arguments(parser) -> None:
    parser.add_argument(
        "--model",
        metavar="PATH",
        help="weights file (default: [model] path, else the bundled model)",
    )
    parser.add_argument(
        "--data",
        nargs="+",
        metavar="PATH",
        help="evaluate these session files or folders instead of rendering",
    )
    parser.add_argument(
        "--textbook",
        action="store_true",
        help="score the textbook set (the authors' recipe, 100 images a class) instead",
    )
    parser.add_argument(
        "--sessions",
        type=_positive,
        default=4,
        metavar="N",
        help="fresh synthetic sessions to render (default 4)",
    )
    add_preset_argument(parser)
    parser.add_argument(
        "--seed",
        type=int,
        default=UNSEEN_SEED,
        metavar="S",
        help=f"seed of the first rendered session (default {UNSEEN_SEED})",
    )
    parser.add_argument(
        "--frames", type=_positive, metavar="N", help="at most N frames per rendered session"
    )
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")


def run(args, config) -> int:
    import logging

    from capture.corpus.dataset import SynthSettings, read_sessions
    from inference.model import load_classifier
    from inference.training import evaluate_sessions, format_metrics

    classifier = load_classifier(
        args.model or config.model.path or None, device=config.model.device
    )
    if args.textbook:
        return _textbook(classifier, args.json)
    if args.data:
        sessions = read_sessions(args.data)
        where = ", ".join(args.data)
    else:
        from tqdm import tqdm

        from capture.corpus.dataset import render_synth_session, session_plan

        settings = SynthSettings(max_frames=args.frames or 0)
        sessions = []
        for preset, seed in tqdm(
            session_plan(args.sessions, args.preset, args.seed),
            desc="render",
            unit="session",
            disable=args.json,
        ):
            sessions.append(
                render_synth_session(
                    preset,
                    seed,
                    config.preprocess,
                    settings,
                    config.simulator,
                    mounting=config.mounting,
                )[0]
            )
        where = f"{len(sessions)} new synthetic sessions (seeds {args.seed}..)"
    seen = set(classifier.metadata.get("data", {}).get("sessions_seen_in_training", []))
    overlap = sorted(seen & {s.name for s in sessions})
    if overlap:
        logging.getLogger(__name__).warning(
            "%d of these sessions were used in training (e.g. %s)", len(overlap), overlap[0]
        )
    metrics = evaluate_sessions(classifier, sessions)
    if args.json:
        print(
            json.dumps(
                {
                    "model": classifier.path,
                    "sessions": [s.name for s in sessions],
                    "metrics": {k: v.to_dict() for k, v in metrics.items()},
                },
                indent=2,
            )
        )
    else:
        print(format_metrics(metrics, f"{classifier.path} on {where}:"))
    return 0


def _textbook(classifier, as_json: bool) -> int:
    import numpy as np

    from inference.textbook import PER_CLASS, TEXTBOOK_SEED, textbook_set
    from inference.training import format_metrics, group_metrics

    images, labels = textbook_set()
    predictions = np.argmax(classifier.predict_batch(images, batch_size=100), axis=1)
    metrics = {"textbook": group_metrics(labels, predictions)}
    if as_json:
        print(json.dumps({"model": classifier.path, "metrics": metrics["textbook"].to_dict()}))
    else:
        title = (
            f"{classifier.path} on the textbook set ({PER_CLASS} images a class, "
            f"seed {TEXTBOOK_SEED}):"
        )
        print(format_metrics(metrics, title))
    return 0
