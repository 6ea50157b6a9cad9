"""Evaluate your own classifier's scores with walkcap's fusion methods and metrics.

    python examples/eval_scores.py trial01.csv trial02.csv ...

Each CSV holds one trial, one row per frame in capture order: the five mode scores and
the true mode (the terrain the image shows), with the header

    LG,US,DS,UR,DR,label

(an optional last column `locomotion` adds the mode the subject was in). The fusion
methods run frame by frame as they do live; accuracy is per trial, then mean and SD over
trials, as in the paper. `walkcap eval scores` prints the same figures and more.
"""

import statistics
import sys

from inference.evaluation import PAPER_METHODS, evaluate, read_scores

FPS = 15.0  # frames a second: the times behind switch rates and delays

trials = [read_scores(path, FPS) for path in sys.argv[1:]]
# To evaluate arrays instead of files: inference.evaluation.Trial(name, probabilities
# (N x 5, columns LG US DS UR DR), reference (N mode names or indices), times_s=...).
results = evaluate(trials, PAPER_METHODS)

for method in PAPER_METHODS:
    accuracies = [r.accuracy[method] for r in results]
    mean = statistics.mean(accuracies)
    sd = statistics.stdev(accuracies) if len(accuracies) > 1 else 0.0
    # Switches the decision made where the terrain did not change, a minute: each one
    # would put a prosthesis in the wrong mode.
    spurious = [r.transitions[method]["terrain"].spurious_per_min for r in results]
    print(
        f"{method:12s} accuracy {100 * mean:6.2f} % (SD {100 * sd:.2f}), "
        f"spurious switches {statistics.mean(spurious):5.1f} / min"
    )

for r in results:
    print(r.trial.path, " ".join(f"{m} {100 * r.accuracy[m]:.1f}" for m in PAPER_METHODS))
