"""A recording as a source for the live screen: play, pause, seek, and label corrections.

`ReplaySource` has the surface of capture.live.session.Session that the screens use
(snapshot, set_label, undo_label, add_marker, ...) plus playback (tui.source.Playback),
so `walkcap replay FILE --tui` shows a recording in the same screens as a live session.

Label corrections never touch the original file: `save_corrections()` writes a new file,
a message-for-message copy of the original (same schemas, channels, bytes, times) with the
corrections added to /labels (source "correction") and to /events (markers), plus a
"corrections" metadata record naming the original (capture.recording.copy). Later changes
win (capture.recording.labels), so a correction at time t applies from t until the next change.
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import datetime as dt
import logging
import os
import struct
from pathlib import Path

import numpy as np

from capture.corpus.trial_pass import FrameRows, Spool
from capture.errors import CaptureError
from capture.live.pipeline import FrameResult
from capture.live.session import Snapshot
from capture.live.timeline import TimelineEntry
from capture.live.trials import SubjectInfo
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.copy import copy_recording
from capture.recording.frames import FrameJoin, frame_rows
from capture.recording.labels import CORRECTION, LabelChange
from capture.recording.lineage import CORRECTED
from capture.recording.metadata import Metadata, SessionRecord
from capture.recording.reader import open_recording
from devices import clock
from devices.base import DeviceEvent, DeviceState, DeviceStatus
from devices.clock import now_ns
from devices.frames import MODES
from inference.fusion import FusionOutput
from inference.preprocess import UNDECIDED

log = logging.getLogger(__name__)

TIMELINE_S = 20.0
PROFILE_POINTS = 600  # per frame kept for the profile plot (the display is ~100 dots wide)
WINDOW_S = (1.0, 1.5)  # images and profiles held before and after the cursor's frame


def _packed_image(data) -> np.ndarray:
    return np.packbits(np.asarray(data) > 0)


def _profile(data) -> np.ndarray:
    cloud = np.asarray(data)
    if len(cloud) > PROFILE_POINTS:
        cloud = cloud[np.linspace(0, len(cloud) - 1, PROFILE_POINTS).astype(int)]
    return cloud[:, [0, 2]].astype(np.float16)  # forward, height


_CHUNK_HEAD = struct.Struct("<BQQQQI")  # opcode, length, start, end, uncompressed size, CRC
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish


class _Window:
    """The images, profiles and terrain features of the frames around the cursor, read
    from a finished file's chunks as the cursor reaches them: each chunk decompressed once
    while it is near, only those messages parsed (by its message index), dropped when the
    cursor has left it. Memory the same whatever the recording's length."""

    TOPICS = (T.BINARY_IMAGE, T.CLOUD, T.FEATURES)

    def __init__(self, rec) -> None:
        from mcap.reader import make_reader

        self.path = rec.path
        self._decode = rec.decoder()
        with open(self.path, "rb") as f:
            summary = make_reader(f).get_summary()
        self._schemas = summary.schemas
        self._channels = {c.id: c for c in summary.channels.values() if c.topic in self.TOPICS}
        self._chunks = sorted(
            (
                c
                for c in summary.chunk_indexes
                if set(c.message_index_offsets) & set(self._channels)
            ),
            key=lambda c: c.message_start_time,
        )
        self._held: dict[int, tuple[dict, dict, dict]] = {}  # chunk offset -> its frames'
        self.images: dict[int, np.ndarray] = {}
        self.profiles: dict[int, np.ndarray] = {}
        self.features: dict[int, dict] = {}

    def around(self, host_ns: int) -> None:
        """Hold the frames of the chunks received within WINDOW_S of `host_ns`."""
        lo, hi = host_ns - clock.to_ns(WINDOW_S[0]), host_ns + clock.to_ns(WINDOW_S[1])
        near = [c for c in self._chunks if c.message_end_time >= lo and c.message_start_time <= hi]
        if {c.chunk_start_offset for c in near} == set(self._held):
            return
        with open(self.path, "rb") as f:
            held = {
                c.chunk_start_offset: self._held.get(c.chunk_start_offset) or self._read(f, c)
                for c in near
            }
        self._held = held
        self.images = {k: v for images, _, _ in held.values() for k, v in images.items()}
        self.profiles = {k: v for _, profiles, _ in held.values() for k, v in profiles.items()}
        self.features = {k: v for *_, features in held.values() for k, v in features.items()}

    def _read(self, f, chunk) -> tuple[dict, dict, dict]:
        import zstandard
        from mcap.records import Message

        f.seek(chunk.chunk_start_offset)
        data = f.read(chunk.chunk_length)
        *_, size, _ = _CHUNK_HEAD.unpack_from(data)
        at = _CHUNK_HEAD.size
        (n,) = struct.unpack_from("<I", data, at)
        compression = data[at + 4 : at + 4 + n].decode()
        at += 4 + n + 8
        records = data[at:]
        if compression == "zstd":
            records = zstandard.ZstdDecompressor().decompress(records, max_output_size=size)
        elif compression:
            raise CaptureError(f"{self.path}: chunks compressed with {compression}")
        images, profiles, features = {}, {}, {}
        for cid, channel in self._channels.items():
            index_at = chunk.message_index_offsets.get(cid)
            if index_at is None:
                continue
            f.seek(index_at)
            head = f.read(15)
            (length,) = struct.unpack_from("<Q", head, 1)
            body = head[9:] + f.read(length - 6)
            pairs = np.frombuffer(body, dtype="<u8", offset=6).reshape(-1, 2)
            for offset in pairs[:, 1]:
                _, length, _, seq, log_time, publish_time = _MESSAGE_HEAD.unpack_from(
                    records, offset
                )
                payload = records[offset + _MESSAGE_HEAD.size : offset + 9 + length]
                message = Message(
                    channel_id=cid,
                    sequence=seq,
                    log_time=log_time,
                    publish_time=publish_time,
                    data=payload,
                )
                m = self._decode(self._schemas.get(channel.schema_id), channel, message)
                if m.topic == T.BINARY_IMAGE:
                    images[m.sequence] = _packed_image(m.data)
                elif m.topic == T.CLOUD:
                    profiles[m.sequence] = _profile(m.data)
                elif shown := _shown_features(m.data):
                    features[int(m.data["frame_index"])] = shown
        return images, profiles, features


def _shown_features(features: dict) -> dict:
    """A frame's terrain features as the screens show them: the numbers and words."""
    return {
        k: v
        for k, v in features.items()
        if k not in ("frame_index", "time_ns") and not isinstance(v, (list, dict))
    }


@dataclasses.dataclass
class _Frames:
    """Everything shown per frame, as arrays in frame order (frames with a CNN output,
    and frames left undecided), from the per-frame table (capture.recording.frames)."""

    index: np.ndarray  # (N,) frame numbers
    time_ns: np.ndarray  # (N,) sample time
    host_ns: np.ndarray  # (N,) receive time
    probabilities: np.ndarray  # (N, 5) float32
    cnn: np.ndarray  # (N,) mode index (int8, as the other modes)
    fused: np.ndarray  # (N,) fused decision recorded for the frame, -1 none
    voted: np.ndarray  # (N,)
    fused_shown: np.ndarray  # (N,) latest fused decision produced at or before the frame
    truth: np.ndarray  # (N,) simulator's mode, -1 none
    # frame -> packed bits of the 100 x 100 image, (M, 2) float16 profile, terrain features
    # (every frame's, or the window's of a finished file: _Window)
    images: dict[int, np.ndarray]
    profiles: dict[int, np.ndarray]
    features: dict[int, dict]
    flags: dict[int, str]  # frame -> its preprocessing flag, where it has one
    stale_upto: np.ndarray  # (N,) frames left undecided up to each

    @classmethod
    def shown(cls, tables, images: dict, profiles: dict, features: dict) -> _Frames:
        """The frames the screens show, from the per-frame table in blocks (FrameTables in
        frame order): classified ones, and undecided ones (stale or bad orientation)."""
        parts: dict[str, list] = collections.defaultdict(list)
        flags: dict[int, str] = {}
        last, stale_before = -1, 0
        for table in tables:
            stale = np.array([f in UNDECIDED for f in table.flag], dtype=bool)
            t = table.select(table.classified | stale)
            features.update(
                (int(i), shown)
                for i, f in zip(t.index, t.features, strict=True)
                if (shown := _shown_features(f))
            )
            flags.update((int(i), f) for i, f in zip(t.index, t.flag, strict=True) if f)
            shown = np.full(len(t), -1, dtype=int)
            for k, made in enumerate(t.produced):  # what the big display showed at frame k
                last = int(made) if made >= 0 else last
                shown[k] = last
            probs = t.probabilities
            finite = np.isfinite(probs)
            cnn = np.where(
                finite.any(axis=1), np.argmax(np.where(finite, probs, -np.inf), axis=1), -1
            )
            stale_upto = stale_before + np.cumsum([f in UNDECIDED for f in t.flag], dtype=int)
            stale_before = int(stale_upto[-1]) if len(stale_upto) else stale_before
            # modes as bytes and the scores as float32: a long trial's arrays a third the size
            for name, values, dtype in (
                ("index", t.index, np.int64),
                ("time_ns", t.time_ns, np.int64),
                ("host_ns", t.host_time_ns, np.int64),
                ("probabilities", probs, np.float32),
                ("cnn", cnn, np.int8),
                ("fused", t.decision, np.int8),
                ("voted", t.voted, np.int8),
                ("fused_shown", shown, np.int8),
                ("truth", t.truth, np.int8),
                ("stale_upto", stale_upto, np.int64),
            ):
                parts[name].append(np.asarray(values).astype(dtype, copy=False))
        columns = {name: np.concatenate(values) for name, values in parts.items()}
        return cls(**columns, images=images, profiles=profiles, features=features, flags=flags)


class ReplaySource:
    """Plays a recording back on the wall clock; the screens pull snapshots from it."""

    def __init__(self, path: str | os.PathLike, *, clock=now_ns, play: bool = True) -> None:
        self.path = Path(path)
        self._clock = clock
        self.playing = False
        self._play_on_start = play
        self._anchor_pos = 0.0  # seconds from the start at `_anchor_wall`
        self._anchor_wall = 0
        self.duration_s = 0.0
        self._start_ns = 0
        self.frames: _Frames | None = None
        self.original_labels: list[tuple[int, str, str]] = []
        self.corrections: list[LabelChange] = []
        self.markers: list[DeviceEvent] = []
        self.events: list[DeviceEvent] = []
        self.meta = Metadata()
        self.subject_info: SubjectInfo | None = None
        self.saved_path: Path | None = None
        self.trial_notice = ""  # a replay records no trial
        self.trial: SubjectInfo | None = None
        self.alarms = None
        self._camera = self._imu = None
        self._changes_cache: tuple[list, np.ndarray] | None = None
        self._unsaved = False
        self._window: _Window | None = None  # a finished file's images, read as shown

    # ---- life cycle -------------------------------------------------------------------

    def start(self) -> None:
        """Read the recording into memory (images packed, profiles decimated)."""
        rec = open_recording(self.path)
        self.meta = rec.meta
        self.frames = self._load(rec)
        n = len(self.frames.index)
        if n == 0:
            raise CaptureError(f"{self.path}: no classified frames to replay")
        self._start_ns = int(self.frames.time_ns[0])
        self.duration_s = clock.seconds(int(self.frames.time_ns[-1]) - self._start_ns)
        self._camera, self._imu = self._device_status(rec, n)
        self.subject_info = _subject_from_metadata(rec.meta.session)
        self._anchor_wall = self._clock()
        self.playing = self._play_on_start

    def _load(self, rec) -> _Frames:
        """The per-frame table, its rows through a spool on disk and kept as the arrays
        shown; the images, profiles and terrain features of a finished file are read
        around the cursor as it moves (_Window), an unfinished file's (no index) all at
        once."""
        images, profiles, features = {}, {}, {}
        topics = FrameJoin.TOPICS
        if rec.complete:
            self._window = _Window(rec)
            topics = tuple(t for t in topics if t not in (T.FEATURES, T.TF))  # not shown

        def take(m) -> None:
            d = m.data
            if m.topic == T.EVENTS:
                self.events.append(
                    DeviceEvent(
                        int(d["time_ns"]),
                        d.get("device", ""),
                        d.get("kind", ""),
                        d.get("message", ""),
                        d.get("details") or {},
                    )
                )
            elif m.topic == T.LABELS:
                changes.append(L.change_from_message(d))
            elif m.topic == T.BINARY_IMAGE:
                images[m.sequence] = _packed_image(d)
            elif m.topic == T.CLOUD:
                profiles[m.sequence] = _profile(d)

        shown = (T.EVENTS,) if rec.complete else (T.EVENTS, T.BINARY_IMAGE, T.CLOUD)
        rows, changes = FrameRows(Spool()), []
        try:
            for m in rec.messages([t for t in (*topics, T.LABELS, *shown) if t in rec.topics]):
                if not rows.add(m):
                    take(m)
            rows.end()
            self.original_labels = L.in_time_order(changes)
            has_truth = T.TRUTH in rec.topics
            tables = (
                frame_rows(block, self.original_labels, has_truth=has_truth)
                for block in rows.blocks()
            )
            frames = _Frames.shown(tables, images, profiles, features)
        finally:
            rows.close()
        self.events.sort(key=lambda e: e.time_ns)
        return frames

    def _device_status(self, rec, frames: int) -> tuple[DeviceStatus, DeviceStatus]:
        devices = self.meta.devices
        camera_backend = devices.camera_backend if devices.has("camera_backend") else "?"
        imu_backend = devices.imu_backend if devices.has("imu_backend") else "?"
        seconds = max(rec.duration_s, 1e-9)
        imu_count = rec.topics[T.IMU].count if T.IMU in rec.topics else 0
        name = self.path.name
        camera = DeviceStatus(
            backend=f"replay of {camera_backend}",
            state=DeviceState.OK,
            message=name,
            configured_rate_hz=float(devices.camera_fps or 0),
            measured_rate_hz=frames / seconds,
            delivered=frames,
        )
        imu = DeviceStatus(
            backend=f"replay of {imu_backend}",
            state=DeviceState.OK,
            configured_rate_hz=float(devices.imu_rate_hz or 0),
            measured_rate_hz=imu_count / seconds,
            delivered=imu_count,
        )
        return camera, imu

    def stop(self) -> None:
        self.playing = False
        return None

    # ---- playback ---------------------------------------------------------------------

    def position(self) -> tuple[float, float]:
        """(seconds from the first frame, duration); playing stops at the end."""
        pos = self._anchor_pos
        if self.playing:
            pos += clock.seconds(self._clock() - self._anchor_wall)
            if pos >= self.duration_s:
                self._anchor(self.duration_s)
                self.playing = False
        return min(max(pos, 0.0), self.duration_s), self.duration_s

    def _anchor(self, pos: float) -> None:
        self._anchor_pos = min(max(pos, 0.0), self.duration_s)
        self._anchor_wall = self._clock()

    def toggle_play(self) -> None:
        pos, _ = self.position()
        if not self.playing and pos >= self.duration_s:
            pos = 0.0  # play again from the start
        self._anchor(pos)
        self.playing = not self.playing

    def seek(self, delta_s: float) -> None:
        pos, _ = self.position()
        self._anchor(pos + delta_s)

    def _cursor(self) -> tuple[int, int]:
        """(position in the frame arrays, time on the recording's clock) now."""
        pos, _ = self.position()
        t = self._start_ns + clock.to_ns(pos)
        k = int(np.searchsorted(self.frames.time_ns, t, side="right")) - 1
        return max(k, 0), t

    # ---- labels -----------------------------------------------------------------------

    def label_changes(self) -> list[tuple[int, str, str]]:
        """The reference: the original changes with their undos applied and the corrections
        (capture.recording.labels), in time order (corrections last on ties)."""
        merged = self.original_labels + [(c.time_ns, c.mode, CORRECTION) for c in self.corrections]
        return L.effective_changes(merged)

    def _labels_at(self, times_ns: np.ndarray) -> np.ndarray:
        return L.labels_at(times_ns, self.label_changes())

    @property
    def label(self) -> str | None:
        if self.frames is None:
            return None
        _, t = self._cursor()
        k = int(self._labels_at(np.array([t]))[0])
        return MODES[k] if k >= 0 else None

    def set_label(
        self, mode: str, source: str = CORRECTION, time_ns: int | None = None
    ) -> LabelChange:
        """The true mode from the frame on screen on (until the next change): the frame the
        operator looks at is the first one relabelled, so the strip shows it at once."""
        if mode not in MODES:
            raise CaptureError(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
        if time_ns is None:
            k, t = self._cursor()
            time_ns = min(t, int(self.frames.time_ns[k])) if len(self.frames.time_ns) else t
        change = LabelChange(int(time_ns), mode, CORRECTION)
        self.corrections.append(change)
        self._unsaved = True
        return change

    def undo_label(self) -> LabelChange | None:
        """Take back the last correction (the original labels are never removed)."""
        if not self.corrections:
            return None
        undone = self.corrections.pop()
        self._unsaved = bool(self.corrections or self.markers)
        return undone

    def add_marker(self, note: str = "", time_ns: int | None = None) -> None:
        _, t = self._cursor()  # in replay a marker sits at the playback position
        self.markers.append(
            DeviceEvent(t, "operator", "marker", note or "marker", {"added_in_replay": True})
        )
        self._unsaved = True

    @property
    def unsaved(self) -> bool:
        return self._unsaved

    # ---- no recording in replay: corrections go to a new file -------------------------

    @property
    def recording(self) -> bool:
        return False

    def start_recording(
        self, info: SubjectInfo, existing: str = "next", folder: str | Path | None = None
    ) -> Path:
        raise CaptureError("a replay does not record: save the corrections to a new file instead")

    def stop_recording(self) -> None:
        return None

    def inject(self, device: str, fault: str, **kw) -> None:
        raise CaptureError("a replay has no devices to inject faults into")

    def save_corrections(self, path: str | os.PathLike | None = None) -> Path:
        """Write the original with the corrections into a new file; returns its path."""
        target = Path(path) if path is not None else corrected_path(self.path)
        write_corrected(self.path, target, self.corrections, self.markers)
        self.saved_path = target
        self._unsaved = False
        return target

    # ---- what the screens read --------------------------------------------------------

    def snapshot(self) -> Snapshot:
        f = self.frames
        k, t = self._cursor()
        i = int(f.index[k])
        if self._window is not None:
            self._window.around(int(f.host_ns[k]))
            f.images, f.profiles = self._window.images, self._window.profiles
            f.features = self._window.features
        image = (
            np.unpackbits(f.images[i])[: 100 * 100].reshape(100, 100)
            if i in f.images
            else np.zeros((100, 100), np.uint8)
        )
        shown = int(f.fused_shown[k])
        latest = FrameResult(
            index=i,
            time_ns=int(f.time_ns[k]),
            host_time_ns=int(f.host_ns[k]),
            orientation=None,
            image=image,
            cloud=np.zeros((0, 3), np.float32),
            profile=f.profiles.get(i, np.zeros((0, 2), np.float16)).astype(np.float32),
            flag=f.flags.get(i, ""),
            probabilities=f.probabilities[k].astype(float),
            cnn_decision=int(f.cnn[k]),
            # the decision the display showed then (the frame it decided is not kept)
            fused=FusionOutput(frame=None, decision=shown) if shown >= 0 else None,
            features=f.features.get(i, {}),
        )
        lo = int(np.searchsorted(f.time_ns, t - clock.to_ns(TIMELINE_S), side="left"))
        times = f.time_ns[lo : k + 1]
        labels = self._labels_at(times)
        timeline = [
            TimelineEntry(
                int(f.index[j]),
                int(f.time_ns[j]),
                MODES[labels[j - lo]] if labels[j - lo] >= 0 else None,
                int(f.cnn[j]),
                int(f.fused[j]) if f.fused[j] >= 0 else None,
                int(f.voted[j]) if f.voted[j] >= 0 else None,
                MODES[f.truth[j]] if f.truth[j] >= 0 else None,
            )
            for j in range(lo, k + 1)
        ]
        events = sorted(self.events + self.markers, key=lambda e: e.time_ns)
        upto = bisect.bisect_right([e.time_ns for e in events], t)
        label = labels[-1] if len(labels) else -1
        return Snapshot(
            time_ns=t,
            running=True,
            camera=self._camera,
            imu=self._imu,
            sync={},
            label=MODES[label] if label >= 0 else None,
            latest=latest,
            timeline=timeline,
            events=events[max(0, upto - 50) : upto],
            recording=None,
            recording_started_ns=None,
            frames=k + 1,
            latency_ms={},
            stale_frames=int(f.stale_upto[k]),
            fusion_method=str(self.meta.software.fusion_method or ""),
        )


def _subject_from_metadata(session: SessionRecord) -> SubjectInfo | None:
    """The recording's session metadata back into a SubjectInfo (best effort, for display)."""
    if not session:
        return None
    kwargs = {}
    for f in dataclasses.fields(SubjectInfo):
        raw = session.value(f.name)
        if raw in (None, ""):
            continue
        try:
            if f.name == "amputee":
                kwargs[f.name] = raw is True or raw in ("True", "true", "1")
            elif f.name in ("trial", "age"):
                kwargs[f.name] = int(raw)
            elif f.name in ("height_m", "weight_kg", "residual_limb_cm"):
                kwargs[f.name] = float(raw)
            else:
                kwargs[f.name] = str(raw)
        except ValueError:
            continue
    return SubjectInfo(**kwargs)


def corrected_path(original: Path) -> Path:
    """`<name>_corrected.mcap` beside the original, numbered when that exists."""
    candidate = original.with_name(f"{original.stem}_corrected{original.suffix}")
    n = 2
    while candidate.exists():
        candidate = original.with_name(f"{original.stem}_corrected{n}{original.suffix}")
        n += 1
    return candidate


def write_corrected(
    original: Path, target: Path, corrections: list[LabelChange], markers: list[DeviceEvent]
) -> Path:
    """Copy `original` message for message into `target` (never overwritten), adding the
    corrections to /labels and the markers to /events (capture.recording.copy)."""
    return copy_recording(
        original,
        target,
        kind=CORRECTED,
        how=f"{len(corrections)} label correction(s)",
        labels=[T.label_json(c.time_ns, c.mode, CORRECTION) for c in corrections],
        events=[T.event_json(e) for e in markers],
        metadata=[
            (
                "corrections",
                {
                    "source": Path(original).name,
                    "source_size": _size(Path(original)),
                    "written": dt.datetime.now().isoformat(timespec="seconds"),
                    "labels": [[c.time_ns, c.mode] for c in corrections],
                    "markers": len(markers),
                    "rule": "label changes apply from their time until the next; "
                    f"corrections have source '{CORRECTION}'",
                },
            )
        ],
    )


def _size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None  # copy_recording names what is wrong with it


def run_tui(path: str | os.PathLike, config) -> int:
    """`walkcap replay FILE --tui`: the recording in the live screens."""
    from tui.app import WalkcapApp
    from tui.logfile import log_path, logging_to_file

    p = Path(path)
    if not p.is_file():
        raise CaptureError(f"{p}: no such file")
    app = WalkcapApp(
        config, session=ReplaySource(p), ask_subject=False, start_status=f"loading {p.name}…"
    )
    with logging_to_file(log_path()):
        app.run()
    if app.start_error:
        raise CaptureError(f"cannot replay {p.name}: {app.start_error}")
    return app.return_code or 0
