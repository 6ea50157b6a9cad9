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
    features: list[dict]  # terrain features (without frame_index, time_ns)
    labels: np.ndarray  # (N,) the labels in force, undos applied, corrections laid over
    locomotion: np.ndarray  # (N,) the mode keyed live, undos applied, corrections not
    terrain: np.ndarray | None  # (N,) what each image shows; None when nothing says
    terrain_source: str | None  # capture.recording.labels.terrain_source

    def __len__(self) -> int:
        return len(self.index)

    def select(self, rows: np.ndarray) -> FrameTable:
        """The table's rows where `rows` (a boolean mask) is true."""
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

    @property
    def geometry(self) -> np.ndarray:
        """The mode each frame's terrain features show (inference.features.shown_mode), -1
        where unknown or not recorded: the cue of fusion (GeometryFusion)."""
        shown = [shown_mode(f.get("kind"), f.get("direction")) for f in self.features]
        return np.array(shown, dtype=int).reshape(-1)

    @property
    def ground_ahead(self) -> np.ndarray:
        """The mode the ground ahead of each frame shows by its slope
        (inference.features.ground_ahead), -1 where not seen or not recorded: the cue of
        fusion (SlopeFusion)."""
        ahead = [ground_ahead(f.get("ahead_slope_deg")) for f in self.features]
        return np.array(ahead, dtype=int).reshape(-1)


def mode_names(modes: np.ndarray) -> list[str]:
    """Mode indices as names, "" where none."""
    return [MODES[k] if k >= 0 else "" for k in modes]


def _numbers(values) -> list[float]:
    return [np.nan if p is None else p for p in values]


class FrameJoin:
    """Collects the per-frame messages of one pass over a recording."""

    TOPICS = (T.CNN, T.FUSED, T.PREPROCESS, T.TF, T.TRUTH, T.FEATURES)

    # Only the fields the table takes are kept, as tuples: a long trial's frames are many.
    def __init__(self) -> None:
        self.cnn: dict[int, tuple[int, int, tuple, int]] = {}  # (time, log, p, decision)
        self.pre: dict[int, tuple[int, int, str, bool, int | None]] = {}  # (time, log, flag,
        # oriented, cloud points)
        self.fused: dict[int, tuple[int, int]] = {}  # frame -> (decision, produced at)
        self.posterior: dict[int, list] = {}
        self.voted: dict[int, tuple[int, int]] = {}
        self.produced: dict[int, int] = {}
        self.truth: dict[int, int] = {}
        self.quaternion: dict[int, np.ndarray] = {}
        self.features: dict[int, dict] = {}

    def add(self, m) -> bool:
        """Take a decoded message (capture.recording.reader.RecordedMessage); False when
        its topic is not a per-frame one."""
        d, topic = m.data, m.topic
        if topic == T.CNN:
            self.cnn[int(d["frame_index"])] = (
                int(d["time_ns"]),
                m.log_time_ns,
                tuple(_numbers(d["probabilities"])),
                L.mode_index(d["decision"]),
            )
        elif topic == T.FUSED:
            made = int(d["source_frame_index"])
            if d.get("decision") is not None:
                decision = L.mode_index(d["decision"])
                self.fused[int(d["frame_index"])] = (decision, made)
                self.produced[made] = decision
            if d.get("posterior") is not None:
                self.posterior[int(d.get("posterior_frame_index", d["frame_index"]))] = d[
                    "posterior"
                ]
            if d.get("voted") is not None and d.get("voted_frame_index") is not None:
                self.voted[int(d["voted_frame_index"])] = (L.mode_index(d["voted"]), made)
        elif topic == T.PREPROCESS:
            self.pre[int(d["frame_index"])] = (
                int(d["time_ns"]),
                m.log_time_ns,
                d.get("flag", "") or "",
                bool(d.get("oriented", False)),
                d.get("cloud_points"),
            )
        elif topic == T.TF:
            self.quaternion[m.sequence] = np.asarray(d, dtype=float)
        elif topic == T.TRUTH:
            self.truth[int(d["frame_index"])] = L.mode_index(d.get("mode"))
        elif topic == T.FEATURES:
            self.features[int(d["frame_index"])] = {
                k: v for k, v in d.items() if k not in ("frame_index", "time_ns")
            }
        else:
            return False
        return True

    def table(self, changes: list[L.LabelChange], *, has_truth: bool) -> FrameTable:
        """The joined table; `changes`: every /labels change of the file, any order."""
        index = np.array(sorted(set(self.cnn) | set(self.pre)), dtype=np.int64)
        n = len(index)
        first = [self.cnn.get(int(i)) or self.pre[int(i)] for i in index]
        times = np.array([f[0] for f in first], dtype=np.int64).reshape(-1)
        probs = np.full((n, len(MODES)), np.nan)
        post = np.full((n, len(MODES)), np.nan)
        quats = np.full((n, 4), np.nan)
        for k, i in enumerate(index.tolist()):
            if i in self.cnn:
                probs[k] = self.cnn[i][2]
            if i in self.posterior:
                post[k] = _numbers(self.posterior[i])
            if i in self.quaternion:
                quats[k] = self.quaternion[i]

        def column(values: dict, default=NONE) -> np.ndarray:
            return np.array([values.get(int(i), default) for i in index], dtype=int)

        pre = [self.pre.get(int(i), (0, 0, "", False, None)) for i in index]
        reference = L.effective_changes(changes)
        labels = L.labels_at(times, reference)
        truth = column(self.truth)
        source = L.terrain_source(has_truth, changes)
        return FrameTable(
            index=index,
            time_ns=times,
            host_time_ns=np.array([f[1] for f in first], dtype=np.int64),
            classified=np.array([int(i) in self.cnn for i in index], dtype=bool),
            probabilities=probs,
            cnn_decision=column({i: c[3] for i, c in self.cnn.items()}),
            decision=column({i: v[0] for i, v in self.fused.items()}),
            decision_at=column({i: v[1] for i, v in self.fused.items()}),
            posterior=post,
            voted=column({i: v[0] for i, v in self.voted.items()}),
            voted_at=column({i: v[1] for i, v in self.voted.items()}),
            produced=column(self.produced),
            truth=truth,
            has_truth=has_truth,
            quaternion=quats,
            flag=[f[2] for f in pre],
            oriented=np.array([f[3] for f in pre], dtype=bool),
            cloud_points=[f[4] for f in pre],
            features=[self.features.get(int(i), {}) for i in index],
            labels=labels,
            locomotion=L.labels_at(times, L.live_changes(reference)),
            terrain=truth if has_truth else labels if source else None,
            terrain_source=source,
        )
