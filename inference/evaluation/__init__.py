"""Evaluating classifiers and fusion the way the paper does, on score files or recordings.

- `trials`: what is evaluated (`Trial`, `FusionRun`, `TrialResult`), read from score CSVs
  (`read_scores`) or from a recording's per-frame table (`trial_from_recording`);
- `metrics`: the methods run frame by frame as live (`run_offline`), accuracy per trial,
  mean and SD, paired t-tests, confusion matrices, the delay sweep;
- `transitions`: switches against a reference: spurious, missed, delay, lead time;
- `report`: the JSON of `walkcap eval --json`;
- `plots`: the paper's figures.

Public API: `Trial`, `TrialResult`, `ScoreFileError`, `read_scores`, `trial_from_recording`,
`evaluate`, `delay_sweep`, `leave_one_out_transitions`, `report`, `write_plots`,
`PAPER_METHODS`, `TITLES`.
"""

from inference.evaluation.metrics import (
    PAPER_METHODS,
    TITLES,
    delay_sweep,
    evaluate,
    leave_one_out_transitions,
)
from inference.evaluation.plots import write_plots
from inference.evaluation.report import report
from inference.evaluation.trials import (
    ScoreFileError,
    Trial,
    TrialResult,
    read_scores,
    trial_from_recording,
)

__all__ = [
    "PAPER_METHODS",
    "TITLES",
    "ScoreFileError",
    "Trial",
    "TrialResult",
    "delay_sweep",
    "evaluate",
    "leave_one_out_transitions",
    "read_scores",
    "report",
    "trial_from_recording",
    "write_plots",
]
