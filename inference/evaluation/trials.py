"""What is evaluated: a trial (CNN probabilities per frame and its references), one
method's run over it, and the trial's result; read from score CSVs (`read_scores`) or from
a recording's per-frame arrays (`trial_from_recording`, from capture.corpus.trials).

Two references: `terrain`, what each image shows (the paper's: labelled offline from the
images, or the simulator's per-image truth), and `locomotion`, the subject's mode keyed live,
which changes about a second after the terrain ahead does.
"""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from devices import clock
from devices.frames import MODES
from inference.errors import InferenceError
from inference.evaluation import errors as er
from inference.evaluation import steps as st
from inference.evaluation import transitions as tr
from inference.fusion_design import N_MODES, mode_indices

log = logging.getLogger(__name__)

SCORE_HEADER = (*MODES, "label")  # label: the terrain each image shows
SCORE_HEADER_LOCOMOTION = (*SCORE_HEADER, "locomotion")  # + the mode keyed live
# optional columns after label, in this order: the mode keyed live, gait events (0/1)
SCORE_OPTIONAL = ("locomotion", "heel_contact", "toe_off")
SUM_TOLERANCE = 0.01  # score rows must sum to 1 within this (they are often rounded)


class ScoreFileError(InferenceError):
    """A score CSV is malformed; the message names the file and line."""


@dataclass
class Trial:
    """One sequence to evaluate: CNN probabilities per frame and the true mode per frame."""

    path: str
    probabilities: np.ndarray  # (N, 5), index order MODES
    reference: Any  # (N,) mode names or indices; None / "" / -1: no reference
    metadata: dict = field(default_factory=dict)  # "subject", "condition", ...
    times_s: np.ndarray | None = None  # (N,) seconds since the first frame; None: unknown
    reference_name: str = "terrain"  # what `reference` is: "terrain" or "locomotion"
    locomotion: Any = None  # (N,) the subject's mode keyed live, when `reference` is terrain
    elevation_deg: np.ndarray | None = None  # (N,) camera above the horizon: gait cues
    geometry: np.ndarray | None = None  # (N,) the mode the terrain features show, -1: unknown
    ground_ahead: np.ndarray | None = None  # (N,) the mode the ground ahead slopes as, -1: unknown
    steps: st.Steps | None = None  # the gait events the per-step metrics score at
    gait_events: list[tuple[float, str]] | None = None  # (time s, event): the step fusion's cue

    def __post_init__(self) -> None:
        self.probabilities = np.asarray(self.probabilities, dtype=float)
        if self.times_s is not None:
            self.times_s = np.asarray(self.times_s, dtype=float)
        if self.probabilities.ndim != 2 or self.probabilities.shape[1] != N_MODES:
            raise InferenceError(
                f"{self.path}: expected probabilities of shape (N, 5), "
                f"got {self.probabilities.shape}"
            )
        try:
            self.reference = mode_indices(self.reference)
        except InferenceError as e:
            raise InferenceError(f"{self.path}: {e}") from None
        if len(self.reference) != len(self.probabilities):
            raise InferenceError(
                f"{self.path}: {len(self.probabilities)} frames but "
                f"{len(self.reference)} reference labels"
            )
        if self.locomotion is not None:
            self.locomotion = mode_indices(self.locomotion)
            if len(self.locomotion) != len(self.probabilities):
                raise InferenceError(
                    f"{self.path}: {len(self.probabilities)} frames but "
                    f"{len(self.locomotion)} locomotion labels"
                )
            if not (self.locomotion >= 0).any():
                self.locomotion = None
        if self.elevation_deg is not None:
            self.elevation_deg = np.asarray(self.elevation_deg, dtype=float)
            if len(self.elevation_deg) != len(self.probabilities):
                raise InferenceError(
                    f"{self.path}: {len(self.probabilities)} frames but "
                    f"{len(self.elevation_deg)} camera elevations"
                )
        for name, what in (("geometry", "terrain geometries"), ("ground_ahead", "grounds ahead")):
            cue = getattr(self, name)
            if cue is not None:
                cue = np.asarray(cue, dtype=int)
                setattr(self, name, cue)
                if len(cue) != len(self.probabilities):
                    raise InferenceError(
                        f"{self.path}: {len(self.probabilities)} frames but {len(cue)} {what}"
                    )

    def references(self) -> dict[str, np.ndarray]:
        """Every reference the trial has, by name (the scored one first)."""
        out = {self.reference_name: self.reference}
        if self.locomotion is not None and self.reference_name != "locomotion":
            out["locomotion"] = self.locomotion
        return out

    @property
    def frames(self) -> int:
        return len(self.reference)

    @property
    def labeled_frames(self) -> int:
        """Frames with a reference mode."""
        return int((self.reference >= 0).sum())

    @property
    def reference_names(self) -> list[str]:
        return list(self.references())

    @property
    def subject(self) -> str:
        return str(self.metadata.get("subject") or Path(self.path).stem)

    @property
    def condition(self) -> str:
        return str(self.metadata.get("condition") or "")

    @property
    def title(self) -> str:
        """The trial as a reader names it: subject, condition, trial number."""
        subject, trial = self.metadata.get("subject"), self.metadata.get("trial")
        if not subject:
            return Path(self.path).stem
        parts = [f"subject {subject}"]
        if self.condition:
            parts.append(self.condition)
        if trial not in (None, ""):
            parts.append(f"trial {trial}")
        return ", ".join(parts)


@dataclass
class TrialSummary:
    """What a report says of a trial (Trial's names and counts) without its per-frame
    arrays: a study's results held for hundreds of trials at once."""

    path: str
    frames: int
    labeled_frames: int
    reference_name: str
    reference_names: list[str]
    metadata: dict = field(default_factory=dict)

    @classmethod
    def of(cls, trial: Trial) -> TrialSummary:
        return cls(
            trial.path,
            trial.frames,
            trial.labeled_frames,
            trial.reference_name,
            trial.reference_names,
            dict(trial.metadata),
        )

    subject = Trial.subject
    condition = Trial.condition
    title = Trial.title


@dataclass
class FusionRun:
    """One method over one sequence; -1 / NaN where a frame got nothing."""

    method: str
    decisions: np.ndarray  # (N,) first stage: argmax, smooth state, filter, smoother
    final: np.ndarray  # (N,) the method's decision (the vote for methods with voting)
    posteriors: np.ndarray  # (N, 5) per frame; NaN where none (HMM: frame 0)


@dataclass
class TrialResult:
    trial: Trial | TrialSummary  # the summary alone once summarized()
    accuracy: dict[str, float]
    runs: dict[str, FusionRun]
    # method -> reference name -> its switches against that reference
    transitions: dict[str, dict[str, tr.TransitionStats]] = field(default_factory=dict)
    steps: dict[str, st.StepStats] = field(default_factory=dict)  # method -> per-step figures
    errors: er.ErrorShape | None = None  # the classifier's own errors (its argmax)

    def summarized(self) -> TrialResult:
        """The accuracies and switches a report needs, without the per-frame arrays (the
        trial's and each method's run: several MB for a long trial). Plots, the delay
        sweep and the confusion matrices need the whole result."""
        return TrialResult(
            TrialSummary.of(self.trial),
            dict(self.accuracy),
            {},
            self.transitions,
            self.steps,
            self.errors,
        )


# ---------------------------------------------------------------------------------------
# inputs


def read_scores(path: str | Path, fps: float = tr.PAPER_FPS) -> Trial:
    """A score CSV: header LG,US,DS,UR,DR,label, one row per frame in capture order, frames
    `fps` a second. `label` is the terrain reference; optional columns after it, in this
    order: `locomotion` (the locomotion reference), `heel_contact` and `toe_off` (1 on the
    first frame at or after each gait event of the instrumented leg, else 0 or empty).
    With `heel_contact` the trial is scored per step (inference.evaluation.steps): each
    step's mode is the `locomotion` column's at its heel contact, else the `label`'s; and
    its events feed the methods that act at steps.

    Every problem is a ScoreFileError naming the file and line (1 = the header).
    """
    path = str(path)
    expected = ",".join(SCORE_HEADER)
    probabilities: list[list[float]] = []
    labels: list[int] = []
    locomotion: list[int] = []
    events: dict[str, list[int]] = {"heel_contact": [], "toe_off": []}
    header_fields = SCORE_HEADER
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = csv.reader(f)
        try:
            header = next(rows, None)
            if header is None or not any(h.strip() for h in header):
                raise ScoreFileError(
                    f"{path}: empty file (expected the header {expected} and one row per frame)"
                )
            header_fields = tuple(h.strip() for h in header)
            if not _score_header_ok(header_fields):
                raise ScoreFileError(
                    f"{path}:1: expected the header {expected} (optionally followed by "
                    f"{','.join(SCORE_OPTIONAL)}, in that order), got {','.join(header)}"
                )
            label_columns = [c for c in header_fields[N_MODES:] if c in ("label", "locomotion")]
            event_columns = header_fields[N_MODES + len(label_columns) :]
            for row in rows:
                line = rows.line_num
                if not row or not any(c.strip() for c in row):
                    continue  # blank lines (often one at the end)
                probabilities.append(_score_row(path, line, row, header_fields))
                for name, column in zip(label_columns, row[N_MODES:]):
                    label = column.strip()
                    if label not in MODES:
                        raise ScoreFileError(
                            f"{path}:{line}: unknown {name} {label!r} "
                            f"(expected one of {', '.join(MODES)})"
                        )
                    (labels if name == "label" else locomotion).append(MODES.index(label))
                first = N_MODES + len(label_columns)
                for name, column in zip(event_columns, row[first:]):
                    flag = column.strip()
                    if flag not in ("", "0", "1"):
                        raise ScoreFileError(
                            f"{path}:{line}: {name}: expected 1 (an event) or 0, got {flag!r}"
                        )
                    if flag == "1":
                        events[name].append(len(probabilities) - 1)
        except csv.Error as e:
            raise ScoreFileError(f"{path}:{rows.line_num}: not valid CSV: {e}") from None
        except UnicodeDecodeError:
            raise ScoreFileError(f"{path}: not a text file (expected CSV)") from None
    if not probabilities:
        raise ScoreFileError(f"{path}: no frames after the header")
    n = len(probabilities)
    times_s = np.arange(n) / fps
    steps, gait_events = None, None
    if "heel_contact" in header_fields:
        hc = np.array(events["heel_contact"], dtype=int)
        step_modes = np.array(locomotion or labels, dtype=int)[hc] if len(hc) else hc
        steps = st.Steps(
            times_s[hc],
            step_modes,
            times_s[np.array(events["toe_off"], dtype=int)],
            source="scores",
            mode_source="locomotion" if locomotion else "terrain",
        )
        gait_events = sorted(
            (float(times_s[k]), name) for name, frames in events.items() for k in frames
        )
    return Trial(
        path,
        np.array(probabilities),
        np.array(labels),
        times_s=times_s,
        locomotion=np.array(locomotion) if locomotion else None,
        steps=steps,
        gait_events=gait_events,
    )


def _score_header_ok(header: tuple[str, ...]) -> bool:
    """LG..DR,label then any of SCORE_OPTIONAL, in their order."""
    if header[: len(SCORE_HEADER)] != SCORE_HEADER:
        return False
    rest = list(header[len(SCORE_HEADER) :])
    order = [c for c in SCORE_OPTIONAL if c in rest]
    return rest == order


def _score_row(
    path: str, line: int, row: list[str], header: tuple[str, ...] = SCORE_HEADER
) -> list[float]:
    if len(row) != len(header):
        raise ScoreFileError(
            f"{path}:{line}: expected {len(header)} fields ({','.join(header)}), got {len(row)}"
        )
    values = []
    for name, text in zip(MODES, row):
        try:
            v = float(text)
        except ValueError:
            raise ScoreFileError(f"{path}:{line}: {name}: not a number: {text.strip()!r}") from None
        if not math.isfinite(v):
            raise ScoreFileError(f"{path}:{line}: {name}: not a finite number: {text.strip()}")
        if v < 0:
            raise ScoreFileError(f"{path}:{line}: {name}: negative probability {v:g}")
        values.append(v)
    total = sum(values)
    if abs(total - 1.0) > SUM_TOLERANCE:
        raise ScoreFileError(
            f"{path}:{line}: probabilities sum to {total:.4g}, expected 1 (within {SUM_TOLERANCE})"
        )
    return values


REFERENCES = ("terrain", "locomotion")
# the per-frame table's own names for the references (truth, labels) and auto are accepted too
_REFERENCE_ALIASES = {"truth": "terrain", "labels": "locomotion", "auto": "terrain"}


def trial_from_recording(path: str, data: Any, reference: str = "terrain") -> Trial:
    """A Trial from one recording's per-frame arrays (capture.corpus.trials.RecordedTrial's
    `evaluation_inputs`).

    data: a mapping (or object) with "probabilities" (N, 5), "terrain" (N modes each image
    shows, or None; a flat dict may give "truth" instead), "locomotion" (N modes keyed live,
    -1/None before the first key; or "labels"), "time_ns" and "metadata" (a flat dict:
    subject, condition, trial); optionally "gait", the recording's gait events
    (devices.frames.GaitEvent or their dicts: time_ns, event, source, mode), which give the
    per-step metrics (`gait_steps`) and the step fusion's cue (the detector's events).
    reference: what accuracy is scored against,
    "terrain" or "locomotion"; the other one, when present, serves the transition metrics.
    Frames without a finite CNN output are left out.
    """

    def get(key: str):
        return data.get(key) if isinstance(data, dict) else getattr(data, key, None)

    def has(key: str) -> bool:
        return key in data if isinstance(data, dict) else hasattr(data, key)

    reference = _REFERENCE_ALIASES.get(reference, reference)
    if reference not in REFERENCES:
        raise InferenceError(f"unknown reference {reference!r} (known: {', '.join(REFERENCES)})")
    terrain = get("terrain") if has("terrain") else get("truth")
    locomotion = get("locomotion") if has("locomotion") else get("labels")

    def usable(seq) -> bool:
        return seq is not None and bool((mode_indices(seq) >= 0).any())

    if reference == "terrain" and not usable(terrain):
        raise InferenceError(
            f"{path}: no terrain reference (what the images show) to score accuracy against: "
            "label the images in `walkcap replay FILE --tui`, or score against the live keys "
            "with --reference locomotion"
        )
    if reference == "locomotion" and not usable(locomotion):
        raise InferenceError(f"{path}: no locomotion labels (keyed live) to compare with")
    chosen = mode_indices(terrain if reference == "terrain" else locomotion)
    second = mode_indices(locomotion) if reference == "terrain" and usable(locomotion) else None
    metadata = dict(get("metadata") or {})
    probabilities = np.asarray(get("probabilities"), dtype=float)
    times = get("time_ns")
    times_s = None
    if times is not None and len(times) == len(chosen) and len(times):
        t = np.asarray(times, dtype=np.int64)
        times_s = clock.seconds(t - t[0])
    elevation = get("camera_elevation_deg")
    if elevation is not None:
        elevation = np.asarray(elevation, dtype=float)
    geometry, ahead = get("geometry"), get("ground_ahead")
    if geometry is not None:
        geometry = np.asarray(geometry, dtype=int)
    if ahead is not None:
        ahead = np.asarray(ahead, dtype=int)
    # a recording without the detector's events still runs the step fusion: it then
    # switches on its hold alone (inference.fusion_steps)
    steps, gait_events = None, []
    gait = get("gait") if has("gait") else None
    if gait and times is not None and len(times):
        t0 = int(np.asarray(times, dtype=np.int64)[0])
        logged = get("gait_logged_ns") if has("gait_logged_ns") else None
        steps, gait_events = gait_steps(gait, t0, times_s, second, logged)
        gait_events = gait_events or []
    finite = np.isfinite(probabilities).all(axis=1) if probabilities.ndim == 2 else None
    if finite is not None and not finite.all():
        log.warning("%s: %d frame(s) without a CNN output left out", path, (~finite).sum())
        probabilities, chosen = probabilities[finite], chosen[finite]
        second = second[finite] if second is not None else None
        times_s = times_s[finite] if times_s is not None else None
        elevation = elevation[finite] if elevation is not None else None
        geometry = geometry[finite] if geometry is not None else None
        ahead = ahead[finite] if ahead is not None else None
    return Trial(
        str(path),
        probabilities,
        chosen,
        metadata,
        times_s,
        reference,
        second,
        elevation,
        geometry,
        ahead,
        steps,
        gait_events,
    )


def _event_field(event, name: str):
    return event.get(name) if isinstance(event, dict) else getattr(event, name, None)


def gait_steps(
    events,
    t0_ns: int,
    times_s: np.ndarray | None,
    locomotion: np.ndarray | None,
    logged_ns=None,
) -> tuple[st.Steps | None, list[tuple[float, str]] | None]:
    """From a recording's gait events (times on the session clock, `t0_ns` the first
    frame's): the steps the per-step metrics score at, and the detector's events as the
    step fusion's cue ((seconds since the first frame, event), in time order): each at
    the later of its time and when it was logged (`logged_ns`, one per event: when the
    detector reported it), as live the fusion gets an event only once it is detected.

    The steps are the simulator's heel contacts with the terrain under the foot where the
    recording has them; else the detector's, each with the locomotion mode (keyed live) in
    force at the frame at or before it; None without either."""
    logged = [None] * len(events) if logged_ns is None else list(logged_ns)
    rows = [
        (
            clock.seconds(int(_event_field(e, "time_ns")) - t0_ns),
            str(_event_field(e, "event")),
            str(_event_field(e, "source")),
            _event_field(e, "mode"),
            None if known is None else clock.seconds(int(known) - t0_ns),
        )
        for e, known in zip(events, logged)
    ]
    rows.sort(key=lambda r: r[0])
    imu = [(t, ev) for t, ev, source, _, _ in rows if source == "imu"]
    detected = sorted(
        (t if known is None else max(t, known), ev)
        for t, ev, source, _, known in rows
        if source == "imu"
    )
    sim = [r[:4] for r in rows if r[2] == "simulator"]
    steps = None
    if any(ev == st.HEEL_CONTACT for _, ev, _, _ in sim):
        hc = [(t, mode) for t, ev, _, mode in sim if ev == st.HEEL_CONTACT]
        steps = st.Steps(
            np.array([t for t, _ in hc]),
            np.array([MODES.index(m) if m in MODES else -1 for _, m in hc], dtype=int),
            np.array([t for t, ev, _, _ in sim if ev == st.TOE_OFF]),
            source="simulator",
            mode_source="simulator",
        )
    elif (
        locomotion is not None
        and times_s is not None
        and any(ev == st.HEEL_CONTACT for _, ev in imu)
    ):
        hc = np.array([t for t, ev in imu if ev == st.HEEL_CONTACT])
        k = np.searchsorted(np.asarray(times_s), hc, side="right") - 1
        modes = np.where(k >= 0, np.asarray(locomotion)[np.maximum(k, 0)], -1)
        steps = st.Steps(
            hc,
            modes,
            np.array([t for t, ev in imu if ev == st.TOE_OFF]),
            source="imu",
            mode_source="locomotion",
        )
    return steps, (detected or None)
