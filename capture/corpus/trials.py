"""A recording as a trial for evaluation: its classified frames and their references.

    trial = read_trial(path)          # RecordedTrial: the classified frames (FrameTable)
    trial.frames.probabilities        # (N, 5) CNN softmax, mode order MODES
    trials = read_trials(paths)       # inference.evaluation.Trial, one a file

The frames are the recording's per-frame table (capture.recording.frames), the rows with
a CNN output; the evaluation trial is built from its arrays by
inference.evaluation.trial_from_recording.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.frames import FrameTable
from capture.recording.metadata import Metadata
from capture.recording.reader import frame_table, open_recording
from devices.frames import MODES, GaitEvent


@dataclass(frozen=True)
class RecordedTrial:
    """One trial's classified frames, in frame order, and what evaluating them needs.

    `frames` (capture.recording.frames.FrameTable): index, time_ns, probabilities,
    cnn_decision, the fused `decision` and `voted` (-1: none), `labels` (the operator's
    mode in force, undos applied, -1 before the first key), `truth` (the simulator's), the
    two references of inference.evaluation (`locomotion`: keyed live; `terrain`: what each
    image shows, the simulator's truth, else the offline labels laid over the live keys,
    else None; `terrain_source`), and the fusion cues (`camera_elevation_deg`,
    `geometry`, `ground_ahead`; the evaluation reads the trial without the terrain
    features themselves: a long trial's would take most of its memory).
    """

    MODES: ClassVar[tuple[str, ...]] = MODES

    path: Path
    id: str
    frames: FrameTable
    unix_time_ns: np.ndarray | None  # the frames' times as Unix time (None: no offset)
    # every recorded change [(time_ns, mode, source)] in time order, undos and what they
    # undid included (the audit trail)
    label_changes: list[L.LabelChange]
    reference_changes: list[L.LabelChange]  # the changes that define frames.labels
    meta: Metadata
    # the gait events (devices.frames.GaitEvent) of /gait and /sim/gait in time order, and
    # when each was logged (the detector's: when it was detected)
    gait: list[GaitEvent] = field(default_factory=list)
    gait_logged_ns: list[int] = field(default_factory=list)

    @property
    def truth(self) -> np.ndarray | None:
        """The simulator's mode per frame; None when the recording has no /sim/truth."""
        return self.frames.truth if self.frames.has_truth else None

    @property
    def metadata(self) -> dict[str, Any]:
        """The evaluation's metadata: every record by name, the session form's fields also
        at the top (subject, condition, trial)."""
        return {**{r.NAME: r.to_dict() for r in self.meta.records() if r}, **self._session()}

    def _session(self) -> dict[str, Any]:
        return self.meta.session.to_dict()

    def evaluation_inputs(self) -> dict[str, Any]:
        """What inference.evaluation.trial_from_recording takes, from the frames."""
        f = self.frames
        return {
            "probabilities": f.probabilities,
            "terrain": f.terrain,
            "locomotion": f.locomotion,
            "time_ns": f.time_ns,
            "camera_elevation_deg": f.camera_elevation_deg,
            "geometry": f.geometry,
            "ground_ahead": f.ground_ahead,
            "metadata": self.metadata,
            "gait": self.gait,
            "gait_logged_ns": self.gait_logged_ns,
        }


def read_trial(path: str | os.PathLike, *, keep_features: bool = True) -> RecordedTrial:
    """One trial's classified frames (frames with a CNN output), in frame order;
    `keep_features` False: the terrain features' cues alone (FrameTable.geometry,
    ground_ahead), not the features (most of a long trial's memory)."""
    rec = open_recording(path)
    gait: list[tuple[GaitEvent, int]] = []  # read in the same pass as the frames

    def take_gait(m) -> None:
        gait.append((T.gait_from_message(m.data), m.log_time_ns))

    # frames with a CNN output only: their preprocessing records not read
    table, changes = frame_table(
        rec,
        (T.GAIT, T.SIM_GAIT),
        take_gait,
        frame_topics=(T.CNN, T.FUSED, T.TF, T.TRUTH, T.FEATURES),
        keep_features=keep_features,
    )
    frames = table.select(table.classified)
    gait.sort(key=lambda g: g[0].time_ns)
    return RecordedTrial(
        path=rec.path,
        id=rec.id,
        frames=frames,
        unix_time_ns=rec.unix_time_ns(frames.time_ns),
        label_changes=changes,
        reference_changes=L.effective_changes(changes),
        meta=rec.meta,
        gait=[e for e, _ in gait],
        gait_logged_ns=[t for _, t in gait],
    )


def read_trials(paths, reference: str = "terrain") -> list:
    """Evaluation trials (inference.evaluation.Trial) from recordings, one a file.

    reference: what accuracy is scored against, "terrain" (what the images show) or
    "locomotion" (the subject's mode keyed live); see RecordedTrial.
    """
    return [read_evaluation_trial(p, reference) for p in paths]


def read_evaluation_trial(path, reference: str = "terrain", name: str | None = None):
    """One recording's evaluation trial (see read_trials), named `name` (default: the
    path); one task of a corpus job (capture.corpus.jobs)."""
    from inference.evaluation import trial_from_recording

    trial = read_trial(path, keep_features=False)
    return trial_from_recording(str(name or path), trial.evaluation_inputs(), reference)
