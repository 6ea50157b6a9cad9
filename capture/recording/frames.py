"""The per-frame table: every per-frame topic of a recording joined by frame index.

    join = FrameJoin()
    for m in rec.messages(FrameJoin.TOPICS + other_topics):
        if not join.add(m):
            ...                                   # a message of another topic
    table = join.table(changes, has_truth=T.TRUTH in rec.topics)

One row per frame with a CNN output or a preprocessing record (a frame left undecided,
its orientation stale, has only the latter), in frame order. What a fused message says
is put on the frame it refers to (`decision`, `posterior`, `voted`), and the frame whose
arrival produced it is kept beside (`decision_at`, `voted_at`, `produced`). The label
references come from capture.recording.labels. `read_trial` (capture.corpus.trials),
`walkcap export` and the replay screen read recordings through this one join.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from capture.recording import labels as L
from capture.recording import topics as T
from devices.frames import MODES
from inference.features import ground_ahead, shown_mode

NONE = -1  # no mode, no frame


@dataclass
class FrameTable:
    """Per-frame arrays, in frame order. Modes are indices into MODES, -1 where none."""

    index: np.ndarray  # (N,) frame numbers
    time_ns: np.ndarray  # (N,) the frame's sample time, session clock
    host_time_ns: np.ndarray  # (N,) receive time of its CNN output (else preprocessing)
    classified: np.ndarray  # (N,) bool: the frame has a CNN output
    probabilities: np.ndarray  # (N, 5) CNN softmax, NaN where none
    cnn_decision: np.ndarray  # (N,) the CNN's decision as recorded
    decision: np.ndarray  # (N,) the fused decision recorded for this frame
    decision_at: np.ndarray  # (N,) the frame whose arrival produced it, -1 none
    posterior: np.ndarray  # (N, 5) the fused posterior for this frame, NaN where none
    voted: np.ndarray  # (N,) the voted decision for this frame
    voted_at: np.ndarray  # (N,) the frame whose arrival produced the vote
    produced: np.ndarray  # (N,) the fused decision produced when this frame arrived
    truth: np.ndarray  # (N,) the simulator's mode (all -1 without /sim/truth)
    has_truth: bool  # the recording has a /sim/truth topic
    quaternion: np.ndarray  # (N, 4) camera -> world [w, x, y, z] (/tf), NaN where none
    flag: list[str]  # preprocessing flag ("" none)
    oriented: np.ndarray  # (N,) bool
    cloud_points: list[int | None]
    features: list[dict]  # terrain features (without frame_index, time_ns); {} when not kept
    # the fusion cues from them: the mode the features show (inference.features.shown_mode)
    # and the mode the ground ahead shows by its slope (inference.features.ground_ahead),
    # -1 where unknown or not recorded
    geometry: np.ndarray  # (N,)
    ground_ahead: np.ndarray  # (N,)
    labels: np.ndarray  # (N,) the labels in force, undos applied, corrections laid over
    locomotion: np.ndarray  # (N,) the mode keyed live, undos applied, corrections not
    terrain: np.ndarray | None  # (N,) what each image shows; None when nothing says
    terrain_source: str | None  # capture.recording.labels.terrain_source

    def __len__(self) -> int:
        return len(self.index)

    def select(self, rows: np.ndarray) -> FrameTable:
        """The table's rows where `rows` (a boolean mask) is true (every row: the same
        columns, not copied)."""
        if np.all(rows):
            return dataclasses.replace(self)
        keep = np.flatnonzero(rows)
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                out[f.name] = value[keep]
            elif isinstance(value, list):
                out[f.name] = [value[k] for k in keep]
            else:
                out[f.name] = value
        return FrameTable(**out)

    @property
    def camera_elevation_deg(self) -> np.ndarray:
        """The camera's optical axis above the horizon (from /tf), NaN without orientation:
        the gait cue of fusion (GaitSteadyFusion)."""
        x, y = self.quaternion[:, 1], self.quaternion[:, 2]
        return np.degrees(np.arcsin(np.clip(1 - 2 * (x * x + y * y), -1.0, 1.0)))

    def __post_init__(self) -> None:
        self.geometry = np.asarray(self.geometry, dtype=np.int8).reshape(-1)
        self.ground_ahead = np.asarray(self.ground_ahead, dtype=np.int8).reshape(-1)


def mode_names(modes: np.ndarray) -> list[str]:
    """Mode indices as names, "" where none."""
    return [MODES[k] if k >= 0 else "" for k in modes]


def _numbers(values) -> list[float]:
    return [np.nan if p is None else p for p in values]


class _Columns:
    """Finished frame rows as growing numpy columns (and lists for the text and dict
    fields): a few hundred bytes a frame instead of a dict entry per topic."""

    NUMBERS = {
        "index": (np.int64, ()),
        "time_ns": (np.int64, ()),
        "host_time_ns": (np.int64, ()),
        "classified": (bool, ()),
        "probabilities": (float, (len(MODES),)),
        "cnn_decision": (np.int64, ()),
        "decision": (np.int64, ()),
        "decision_at": (np.int64, ()),
        "posterior": (float, (len(MODES),)),
        "voted": (np.int64, ()),
        "voted_at": (np.int64, ()),
        "produced": (np.int64, ()),
        "truth": (np.int64, ()),
        "quaternion": (float, (4,)),
        "oriented": (bool, ()),
        "geometry": (np.int8, ()),
        "ground_ahead": (np.int8, ()),
    }
    LISTS = ("flag", "cloud_points", "features")

    def __init__(self, capacity: int = 1024, *, keep_features: bool = True) -> None:
        """`capacity`: the rows expected (the columns grow past it); `keep_features` False:
        each row's terrain features are reduced to their cues (geometry, ground_ahead)."""
        self.n = 0
        rows = max(int(capacity), 16)
        self.arrays = {k: np.empty((rows, *s), dtype=t) for k, (t, s) in self.NUMBERS.items()}
        self.lists: dict[str, list] = {k: [] for k in self.LISTS}
        self.keep_features = keep_features

    def append(self, k: int, e: dict) -> None:
        if self.n == len(self.arrays["index"]):
            for name, a in self.arrays.items():
                self.arrays[name] = np.concatenate([a, np.empty_like(a[: len(a) // 2 + 1])])
        self.set(self.n, _row(k, e, self.keep_features))
        self.n += 1

    def set(self, at: int, row: dict) -> None:
        for name, value in row.items():
            if name in self.lists:
                if at == len(self.lists[name]):
                    self.lists[name].append(value)
                else:
                    self.lists[name][at] = value
            else:
                self.arrays[name][at] = value

    @classmethod
    def of(cls, columns: dict) -> _Columns:
        """Rows from columns that take() gave."""
        rows = cls()
        rows.n = len(columns["index"])
        rows.arrays = {k: np.array(columns[k]) for k in cls.NUMBERS}
        rows.lists = {k: list(columns[k]) for k in cls.LISTS}
        return rows

    def take(self) -> dict:
        """The columns, in frame order."""
        out: dict = {k: a[: self.n] for k, a in self.arrays.items()}
        order = np.argsort(out["index"], kind="stable")
        if np.any(order != np.arange(self.n)):  # a late frame appended after later ones
            out = {k: a[order] for k, a in out.items()}
            self.lists = {k: [v[j] for j in order] for k, v in self.lists.items()}
        return out | self.lists


_NO_FEATURES: dict = {}  # a row's features when not kept (shared: never changed)


def _row(k: int, e: dict, keep_features: bool = True) -> dict:
    """One frame's row from its collected messages (see FrameJoin.add)."""
    cnn, pre = e.get("cnn"), e.get("pre", (0, 0, "", False, None))
    first = cnn or pre
    fused, voted = e.get("fused", (NONE, NONE)), e.get("voted", (NONE, NONE))
    posterior = e.get("posterior")
    quaternion = e.get("quaternion")
    features = e.get("features", _NO_FEATURES)
    return {
        "index": k,
        "time_ns": first[0],
        "host_time_ns": first[1],
        "classified": cnn is not None,
        "probabilities": np.nan if cnn is None else cnn[2],
        "cnn_decision": NONE if cnn is None else cnn[3],
        "decision": fused[0],
        "decision_at": fused[1],
        "posterior": np.nan if posterior is None else _numbers(posterior),
        "voted": voted[0],
        "voted_at": voted[1],
        "produced": e.get("produced", NONE),
        "truth": e.get("truth", NONE),
        "quaternion": np.nan if quaternion is None else quaternion,
        "oriented": pre[3],
        "flag": pre[2],
        "cloud_points": pre[4],
        "features": features if keep_features else _NO_FEATURES,
        **_cues(features),
    }


def _cues(features: dict) -> dict:
    """The fusion cues of a frame's recorded terrain features, -1 where unknown (a
    foreign file's field of another type too)."""
    try:
        shown = shown_mode(features.get("kind"), features.get("direction"))
    except (TypeError, ValueError):
        shown = -1
    try:
        ahead = ground_ahead(features.get("ahead_slope_deg"))
    except (TypeError, ValueError):
        ahead = -1
    return {"geometry": shown, "ground_ahead": ahead}


# the row's columns each collected message sets
_COLUMNS_OF = {
    "cnn": ("time_ns", "host_time_ns", "classified", "probabilities", "cnn_decision"),
    "pre": ("flag", "oriented", "cloud_points"),
    "fused": ("decision", "decision_at"),
    "posterior": ("posterior",),
    "voted": ("voted", "voted_at"),
    "produced": ("produced",),
    "truth": ("truth",),
    "quaternion": ("quaternion",),
    "features": ("features", "geometry", "ground_ahead"),
}


class FrameJoin:
    """Collects the per-frame messages of one pass over a recording, holding only the
    frames still open: a frame's row is finished once the newest frame (by its CNN output
    or preprocessing record) is `lateness` frames past it. Messages are logged in near
    frame order (the fused decision, the latest, refers at most the vote delay back, 2
    frames on the recorded trials); a message for a frame already finished is kept aside
    and laid over its row when the table is made, so the table is the same whatever the
    window."""

    TOPICS = (T.CNN, T.FUSED, T.PREPROCESS, T.TF, T.TRUTH, T.FEATURES)
    LATENESS = 64  # frames, about 1.4 s at 45 fps
    _BATCH = 16  # frames finished together

    def __init__(
        self, lateness: int = LATENESS, *, capacity: int = 1024, keep_features: bool = True
    ) -> None:
        """`capacity`: the frames expected; `keep_features` False: the rows keep the terrain
        features' cues alone (FrameTable.geometry, ground_ahead), not the features."""
        self.lateness = lateness
        self.open: dict[int, dict] = {}  # frame -> what its messages said so far
        self.late: dict[int, dict] = {}  # the same, for frames already finished
        self.newest = NONE
        self.finished_to = NONE  # every frame up to this one is finished
        self.held_peak = 0  # the most frames open at once
        self.keep_features = keep_features
        self.rows = _Columns(capacity, keep_features=keep_features)

    def _entry(self, k: int) -> dict:
        if k <= self.finished_to:
            return self.late.setdefault(k, {})
        return self.open.setdefault(k, {})

    def add(self, m) -> bool:
        """Take a decoded message (capture.recording.reader.RecordedMessage); False when
        its topic is not a per-frame one."""
        d, topic = m.data, m.topic
        if topic == T.CNN:
            k = int(d["frame_index"])
            self._entry(k)["cnn"] = (
                int(d["time_ns"]),
                m.log_time_ns,
                tuple(_numbers(d["probabilities"])),
                L.mode_index(d["decision"]),
            )
            self._advance(k)
        elif topic == T.FUSED:
            made = int(d["source_frame_index"])
            if d.get("decision") is not None:
                decision = L.mode_index(d["decision"])
                self._entry(int(d["frame_index"]))["fused"] = (decision, made)
                self._entry(made)["produced"] = decision
            if d.get("posterior") is not None:
                at = int(d.get("posterior_frame_index", d["frame_index"]))
                self._entry(at)["posterior"] = d["posterior"]
            if d.get("voted") is not None and d.get("voted_frame_index") is not None:
                self._entry(int(d["voted_frame_index"]))["voted"] = (
                    L.mode_index(d["voted"]),
                    made,
                )
        elif topic == T.PREPROCESS:
            k = int(d["frame_index"])
            self._entry(k)["pre"] = (
                int(d["time_ns"]),
                m.log_time_ns,
                d.get("flag", "") or "",
                bool(d.get("oriented", False)),
                d.get("cloud_points"),
            )
            self._advance(k)
        elif topic == T.TF:
            self._entry(m.sequence)["quaternion"] = np.asarray(d, dtype=float)
        elif topic == T.TRUTH:
            self._entry(int(d["frame_index"]))["truth"] = L.mode_index(d.get("mode"))
        elif topic == T.FEATURES:
            self._entry(int(d["frame_index"]))["features"] = {
                k: v for k, v in d.items() if k not in ("frame_index", "time_ns")
            }
        else:
            return False
        self.held_peak = max(self.held_peak, len(self.open))
        return True

    def _advance(self, k: int) -> None:
        self.newest = max(self.newest, k)
        if self.newest - self.lateness >= self.finished_to + self._BATCH:
            self._finish(self.newest - self.lateness)

    def _finish(self, upto: int | float) -> None:
        for k in sorted(k for k in self.open if k <= upto):
            e = self.open.pop(k)
            if "cnn" in e or "pre" in e:
                self.rows.append(k, e)
            else:  # no row (yet): its CNN output or preprocessing may still come
                self.late[k] = e
        if upto != float("inf"):
            self.finished_to = max(self.finished_to, int(upto))

    def _lay_late(self) -> None:
        """Lay the messages that came after their frame was finished over its row (a
        frame's later message replaces an earlier one of its topic, as in one pass)."""
        lay_late(self.rows, self.late, append=True)
        self.late = {}

    def table(self, changes: list[L.LabelChange], *, has_truth: bool) -> FrameTable:
        """The joined table; `changes`: every /labels change of the file, any order."""
        self._finish(float("inf"))
        self._lay_late()
        return frame_rows(self.rows.take(), changes, has_truth=has_truth)

    def finished(self, at_least: int = 1) -> dict | None:
        """The rows finished since the last call, as columns in frame order, once there
        are `at_least` of them (else None): for a reader that writes rows as they are
        finished. The messages that come later for them stay in `late`, for lay_late."""
        if self.rows.n < max(at_least, 1):
            return None
        block, self.rows = self.rows.take(), _Columns(keep_features=self.keep_features)
        return block

    def end(self) -> None:
        """The pass is over: every open frame is finished (finished() gives them)."""
        self._finish(float("inf"))


def lay_late(rows: _Columns, late: dict[int, dict], *, append: bool) -> set[int]:
    """Lay `late` (FrameJoin.late: frame -> what its messages said after the frame was
    finished) over `rows`; with `append`, a frame without a row that has its CNN output or
    preprocessing record becomes one. The frames laid or appended."""
    n = rows.n
    at = {int(k): j for j, k in enumerate(rows.arrays["index"][:n])}
    laid = set()
    for k, e in sorted(late.items()):
        if k not in at:
            if append and ("cnn" in e or "pre" in e):
                rows.append(k, e)
                laid.add(k)
            continue
        j = at[k]
        columns = [c for key in e for c in _COLUMNS_OF[key]]
        if "pre" in e and "cnn" not in e and not rows.arrays["classified"][j]:
            columns += ["time_ns", "host_time_ns"]  # a frame's time: its CNN's, else this
        row = _row(k, e, rows.keep_features)
        rows.set(j, {name: row[name] for name in columns})
        laid.add(k)
    return laid


def frame_rows(c: dict, changes: list[L.LabelChange], *, has_truth: bool) -> FrameTable:
    """A FrameTable of joined rows (columns as FrameJoin gives them, in frame order: the
    whole table or a block of it), the label references laid over them; `changes`: every
    /labels change of the file, any order."""
    times = c["time_ns"]
    reference = L.effective_changes(changes)
    labels = L.labels_at(times, reference)
    truth = c["truth"].astype(int)
    source = L.terrain_source(has_truth, changes)
    return FrameTable(
        index=c["index"],
        time_ns=times,
        host_time_ns=c["host_time_ns"],
        classified=c["classified"],
        probabilities=c["probabilities"],
        cnn_decision=c["cnn_decision"].astype(int),
        decision=c["decision"].astype(int),
        decision_at=c["decision_at"].astype(int),
        posterior=c["posterior"],
        voted=c["voted"].astype(int),
        voted_at=c["voted_at"].astype(int),
        produced=c["produced"].astype(int),
        truth=truth,
        has_truth=has_truth,
        quaternion=c["quaternion"],
        flag=c["flag"],
        oriented=c["oriented"],
        cloud_points=c["cloud_points"],
        features=c["features"],
        geometry=c["geometry"],
        ground_ahead=c["ground_ahead"],
        labels=labels,
        locomotion=L.labels_at(times, L.live_changes(reference)),
        terrain=truth if has_truth else labels if source else None,
        terrain_source=source,
    )
