"""`walkcap train`: train the terrain classifier

    walkcap train --data DIR|FILE ... [--out PATH] [--epochs N] [--seed S] ...
                  [--cluster ADDRESS|local [--workers N]]

Reads labelled sessions (`walkcap synth --format dataset` output; recordings with
operator labels), splits them by session into train / validation /
test, trains with class balancing, augmentation and early stopping, writes the weights
(PATH, a PyTorch state dict) and PATH.json (metadata), and prints per-class accuracy and
the confusion matrix on the held-out test sessions, indoor and outdoor.
"""

from __future__ import annotations

import sys

from tui.commands import count

HELP = "train the terrain classifier"

# The flags that set the TrainSettings field of their name: (flag, type, metavar, help).
# The default is the field's; "{}" in the help shows it.
_SETTINGS = (
    ("--epochs", count(1), "N", "at most N epochs (default {})"),
    ("--batch-size", count(1), "N", "images per training step (default {})"),
    ("--lr", float, None, "learning rate (default {})"),
    ("--patience", count(1), "N", "stop after N epochs without progress (default {})"),
    ("--seed", int, "S", "seed of the split, sampling, augmentation and initialisation"),
    ("--hidden", count(1), "N", "width of the hidden fully connected layer (default {})"),
    (
        "--samples-per-epoch",
        count(1),
        "N",
        "frames drawn per epoch (default: the training set's size)",
    ),
    ("--max-steps", count(1), "N", "stop after N optimiser steps (quick checks)"),
    ("--threads", count(1), "N", "CPU threads for torch (default: torch's choice)"),
    (
        "--val-fraction",
        float,
        "F",
        "share of the sessions held out for early stopping, whole sessions (default {})",
    ),
    (
        "--test-fraction",
        float,
        "F",
        "share of the sessions held out for the final test, unseen in training (default {})",
    ),
    (
        "--balance-power",
        float,
        "P",
        "sample frames with weight class_frequency**-P: "
        "1 balances fully, 0 not at all (default {})",
    ),
)


def _field(flag: str) -> str:
    return flag[2:].replace("-", "_")


def add_arguments(parser) -> None:
    # plain values, no torch: every walkcap command builds this parser
    from inference.training.settings import TrainSettings

    d = TrainSettings()
    parser.add_argument(
        "--data",
        nargs="+",
        required=True,
        metavar="PATH",
        help="session files or folders: .npz from `walkcap synth`, .mcap "
        "recordings (labelled by the operator)",
    )
    parser.add_argument(
        "-o",
        "--out",
        default="runs/terrain_cnn.pt",
        metavar="PATH",
        help="weights file to write; metadata goes to PATH with .json "
        "(default runs/terrain_cnn.pt)",
    )
    for flag, kind, metavar, text in _SETTINGS:
        default = getattr(d, _field(flag))
        parser.add_argument(
            flag, type=kind, default=default, metavar=metavar, help=text.format(default)
        )
    parser.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default=None,
        help="default: [model] device (auto: the GPU when there is one)",
    )
    parser.add_argument(
        "--max-minutes",
        type=float,
        default=None,
        metavar="M",
        help="wall-clock budget: stop training after M minutes",
    )
    parser.add_argument(
        "--no-augment", action="store_true", help="no augmentation (nor mirrored ascents)"
    )
    parser.add_argument("--no-balance", action="store_true", help="no class balancing")
    parser.add_argument(
        "--no-bf16",
        action="store_true",
        help="train in float32 even where the CPU has native bfloat16",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the result (split, best epoch, test metrics, files) as JSON (no bars)",
    )
    parser.add_argument(
        "--cluster",
        metavar="ADDRESS|local",
        help="train on a Ray cluster with torch DistributedDataParallel (Ray Train): "
        "'local' starts one on this machine's cores, an address joins a running one; "
        "each worker reads the sessions (the files at the same paths on every node) and "
        "takes its share of every batch (default: this process)",
    )
    parser.add_argument(
        "--workers",
        type=count(1),
        default=None,
        metavar="N",
        help="with --cluster: training processes (default: one per CPU of the cluster, "
        "at most one per 16 images of a batch)",
    )


def run(args, config) -> int:
    from capture.corpus.dataset import read_sessions, select_session_files
    from inference.model import file_sha256
    from inference.preprocess import metadata as preprocess_metadata
    from inference.training import (
        TrainSettings,
        format_metrics,
        keep_freed_memory,
        save_result,
        train,
    )

    settings = TrainSettings(
        **{_field(flag): getattr(args, _field(flag)) for flag, *_ in _SETTINGS},
        device=args.device or config.model.device,
        augment=not args.no_augment,
        balance=not args.no_balance,
        bf16=not args.no_bf16,
        max_seconds=(args.max_minutes or 0) * 60,
    )
    keep_freed_memory()  # this process only trains
    files, left_out = select_session_files(args.data)
    for line in left_out:
        print(line, file=sys.stderr)
    quiet = args.quiet or args.json
    if args.cluster:  # the workers read the sessions; here only the first, for its metadata
        result = _train_on_cluster(args, settings, files, quiet)
        sessions = read_sessions(files[:1])
        n_sessions, frames = len(files), sum(part["frames"] for part in result.data.values())
        what = "labelled frames"
    else:
        if args.workers:
            from inference.errors import InferenceError

            raise InferenceError("--workers is for --cluster (training processes)")
        sessions = read_sessions(files)
        n_sessions, frames, what = len(sessions), sum(len(s) for s in sessions), "frames"
    if not args.json:
        print(f"{n_sessions} sessions, {frames} {what} from {', '.join(args.data)}")
    preprocess = _preprocess_params(sessions) or preprocess_metadata(
        config.preprocess, config.mounting
    )
    if not args.cluster:
        result = train(sessions, settings, show_progress=not quiet)
    path = save_result(result, args.out, settings, preprocess, [str(f) for f in files])
    split = result.split
    if args.json:
        import json

        print(
            json.dumps(
                {
                    "sessions": n_sessions,
                    "frames": frames,
                    "best_epoch": result.best_epoch,
                    "epochs": len(result.history),
                    "stopped_early": result.stopped_early,
                    "seconds": result.seconds,
                    "split": {k: len(v) for k, v in split.items()},
                    "test": {k: v.to_dict() for k, v in result.test_metrics.items()},
                    "weights": str(path),
                    "sha256": file_sha256(path),
                    "metadata": str(path.with_suffix(".json")),
                },
                indent=2,
                default=str,
            )
        )
        return 0
    print(
        f"best epoch {result.best_epoch} of {len(result.history)}"
        f"{' (early stop)' if result.stopped_early else ''}, {result.seconds:.0f} s; "
        f"sessions: {len(split['train'])} train, {len(split['validation'])} validation, "
        f"{len(split['test'])} test"
    )
    if result.test_metrics:
        print(format_metrics(result.test_metrics, "test sessions (unseen in training):"))
    else:
        print("no test sessions (--test-fraction 0 or too few sessions)")
    print(f"wrote {path} (sha256 {file_sha256(path)[:12]}) and {path.with_suffix('.json')}")
    return 0


def _preprocess_params(sessions) -> dict | None:
    """The preprocessing the sessions were made with, without the per-session mounting."""
    for s in sessions:
        params = s.meta.get("preprocess")
        if params:
            return {k: v for k, v in params.items() if not k.startswith("mounting_")}
    return None


def _train_on_cluster(args, settings, files, quiet: bool):
    from capture.corpus import cluster
    from capture.corpus.dataset import read_sessions

    with cluster.connect(args.cluster, worker_logs=False) as resources:
        workers = cluster.training_workers(
            settings.batch_size, resources.get("CPU", 1), args.workers or 0
        )
        print(f"training on {workers} worker(s) of the cluster (DDP, gloo)", file=sys.stderr)
        return cluster.train(files, settings, workers, read_sessions, show_progress=not quiet)
