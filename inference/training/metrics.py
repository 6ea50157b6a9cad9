"""Measuring a classifier per frame: accuracy, balanced accuracy, per class, confusion,
per session, and where the errors fall on synthesized sessions."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from devices.frames import MODES
from inference.dataset import LabeledSession
from inference.errors import InferenceError
from inference.evaluation.metrics import confusion_matrix, decisions_of, mean_sd
from inference.model import Classifier


@dataclass
class GroupMetrics:
    """Per-frame quality of one group of frames (all, indoor, outdoor)."""

    frames: int
    accuracy: float  # fraction of frames right
    balanced_accuracy: float  # mean of the per-class accuracies present
    per_class: dict  # mode -> accuracy (recall), None when the class is absent
    confusion: list  # 5 x 5 counts, rows true mode, columns predicted mode
    # Where the errors fall, when the sessions carry the simulator's truth (see
    # error_breakdown); None otherwise.
    breakdown: dict | None = None
    # Each session's own accuracy (evaluate_sessions): how far one walk's figure strays.
    session_accuracy: list | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def group_metrics(labels: np.ndarray, predictions: np.ndarray) -> GroupMetrics:
    labels = np.asarray(labels)
    cm = confusion_matrix(np.asarray(predictions), labels)
    # every labelled frame counts, an undecided one (-1: no finite output) as wrong
    return confusion_metrics(
        cm, np.bincount(labels[labels >= 0], minlength=len(MODES))[: len(MODES)]
    )


def confusion_metrics(cm: np.ndarray, totals: np.ndarray | None = None) -> GroupMetrics:
    """Metrics from a confusion matrix; `totals`: frames per true mode (default: its rows)."""
    totals = cm.sum(axis=1) if totals is None else totals
    per_class = {
        m: (float(cm[i, i] / totals[i]) if totals[i] else None) for i, m in enumerate(MODES)
    }
    present = [v for v in per_class.values() if v is not None]
    frames = int(totals.sum())
    return GroupMetrics(
        frames=frames,
        accuracy=float(np.trace(cm) / frames) if frames else float("nan"),
        balanced_accuracy=float(np.mean(present)) if present else float("nan"),
        per_class=per_class,
        confusion=cm.tolist(),
    )


# Where a classifier's errors fall, on synthesized sessions (their simulator truth says which
# mode the walker itself is in and which frames are error images). The truth is what each
# image shows, so near a change it leads the walker's own mode (the camera looks ahead) or,
# on a thigh swung back, lags it; the "locomotion oracle" (the walker's mode as the answer)
# is how far that is from answering the image. Groups, first match wins:
BREAKDOWN_GROUPS = (
    "error image",
    "near a mode change, the walker is in another mode",
    "near a mode change, the walker is in the mode",
    "elsewhere",
)
NEAR_CHANGE_S = 1.0  # "near a mode change": within this long of one


def frame_groups(
    labels: np.ndarray, locomotion_modes: np.ndarray, errors: np.ndarray, near_frames: int
) -> np.ndarray:
    """Each frame's index in BREAKDOWN_GROUPS; one walk's labelled frames, in order."""
    labels = np.asarray(labels)
    n = len(labels)
    changes = np.flatnonzero(np.diff(labels)) + 1  # first frame of each new mode
    near = np.zeros(n, bool)
    if len(changes):
        i = np.arange(n)
        after = np.clip(np.searchsorted(changes, i), 0, len(changes) - 1)
        before = np.clip(after - 1, 0, len(changes) - 1)
        distance = np.minimum(np.abs(i - changes[after]), np.abs(i - changes[before]))
        near = distance < near_frames
    shows = np.asarray(locomotion_modes) == np.asarray(MODES)[labels]
    return np.where(np.asarray(errors) != "", 0, np.where(near, np.where(shows, 2, 1), 3))


def error_breakdown(
    groups: np.ndarray, right: np.ndarray, walker_right: np.ndarray, near_frames: int
) -> dict:
    """Share of frames, accuracy and points of accuracy lost per group; the locomotion oracle."""
    total = len(groups)
    parts = {}
    for g, name in enumerate(BREAKDOWN_GROUPS):
        mask = groups == g
        n = int(mask.sum())
        parts[name] = {
            "frames": n,
            "accuracy": float(right[mask].mean()) if n else None,
            "points_lost": float((mask & ~right).sum() / total * 100),
        }
    return {
        "near_frames": near_frames,
        "locomotion_accuracy": float(walker_right.mean()),
        "groups": parts,
    }


def evaluate_sessions(
    classifier: Classifier, sessions: list[LabeledSession]
) -> dict[str, GroupMetrics]:
    """Per-frame quality, all frames and per preset ("all", "indoor", "outdoor", ...);
    with the error breakdown when every session carries the simulator's truth."""
    labels: dict[str, list[np.ndarray]] = {"all": []}
    preds: dict[str, list[np.ndarray]] = {"all": []}
    per_session: dict[str, list[float]] = {"all": []}
    groups: dict[str, list[np.ndarray]] = {"all": []}
    views: dict[str, list[np.ndarray]] = {"all": []}
    near_frames = 0
    with_truth = all(s.locomotion_modes is not None and s.errors is not None for s in sessions)
    for s in sessions:
        s = s.labelled()
        if not len(s):
            continue
        p = decisions_of(classifier.predict_batch(s.images))
        for key in ("all", s.preset or "unknown"):
            labels.setdefault(key, []).append(s.labels)
            preds.setdefault(key, []).append(p)
            per_session.setdefault(key, []).append(float(np.mean(p == s.labels)))
        if with_truth:
            near_frames = max(1, int(round(NEAR_CHANGE_S * s.meta.get("fps", 15))))
            g = frame_groups(s.labels, s.locomotion_modes, s.errors, near_frames)
            walker_right = s.locomotion_modes == np.asarray(MODES)[s.labels]
            for key in ("all", s.preset or "unknown"):
                groups.setdefault(key, []).append(g)
                views.setdefault(key, []).append(walker_right)
    if not labels["all"]:
        raise InferenceError("no labelled frames to evaluate")
    out = {}
    for k in labels:
        y, p = np.concatenate(labels[k]), np.concatenate(preds[k])
        out[k] = group_metrics(y, p)
        out[k].session_accuracy = per_session[k]
        if with_truth:
            out[k].breakdown = error_breakdown(
                np.concatenate(groups[k]), p == y, np.concatenate(views[k]), near_frames
            )
    return out


def format_metrics(metrics: dict[str, GroupMetrics], title: str = "") -> str:
    """A readable report: accuracy per group, per class, and the confusion matrices."""
    lines = [title] if title else []
    for group, m in metrics.items():
        lines.append(
            f"{group}: {m.accuracy * 100:.2f} % of {m.frames} frames "
            f"(balanced {m.balanced_accuracy * 100:.2f} %)"
        )
        if m.session_accuracy and len(m.session_accuracy) > 1:
            mean, sd = mean_sd(m.session_accuracy)
            lines.append(
                f"  per session: mean {mean * 100:.2f} %, SD {sd * 100:.2f} points, "
                f"{min(m.session_accuracy) * 100:.1f}-"
                f"{max(m.session_accuracy) * 100:.1f} % over "
                f"{len(m.session_accuracy)} sessions"
            )
        lines.append(
            "  per class: "
            + "  ".join(
                f"{k} {'-' if v is None else f'{v * 100:.1f}'}" for k, v in m.per_class.items()
            )
        )
        lines.append("  confusion (rows true, columns predicted):")
        lines.append("        " + "".join(f"{k:>7}" for k in MODES))
        for k, row in zip(MODES, m.confusion):
            lines.append(f"    {k:>4}" + "".join(f"{v:>7}" for v in row))
        if m.breakdown:
            lines += _format_breakdown(m.breakdown, m.frames)
    return "\n".join(lines)


def _format_breakdown(b: dict, frames: int) -> list[str]:
    lines = [
        f"  where the errors are (near: within {b['near_frames']} frames of a change of "
        f"the true mode):"
    ]
    for name, part in b["groups"].items():
        right = "-" if part["accuracy"] is None else f"{part['accuracy'] * 100:.1f} %"
        lines.append(
            f"    {name:<48} {part['frames'] / frames * 100:5.1f} % of frames, "
            f"{right:>7} right, {part['points_lost']:.2f} points lost"
        )
    lines.append(
        f"  locomotion oracle (answering the mode the walker is in): "
        f"{b['locomotion_accuracy'] * 100:.2f} %"
    )
    return lines
