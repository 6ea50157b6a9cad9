"""A recording as a source for the live screen: play, pause, seek, and label corrections.

`ReplaySource` has the surface of capture.live.session.Session that the screens use
(snapshot, set_label, undo_label, add_marker, ...) plus playback (tui.source.Playback),
so `walkcap replay FILE --tui` shows a recording in the same screens as a live session.

Label corrections never touch the original file: `save_corrections()` writes a new file,
a message-for-message copy of the original (same schemas, channels, bytes, times) with the
corrections added to /labels (source "correction") and to /events (markers), plus a
"corrections" metadata record naming the original. Later changes win (capture.recording.reader
labels_at), so a correction at time t applies from t until the next change.
"""

from __future__ import annotations

import bisect
import dataclasses
import datetime as dt
import logging
import os
import uuid
from pathlib import Path

import numpy as np

from capture.errors import CaptureError
from capture.live.labels import LabelChange
from capture.live.pipeline import FrameResult
from capture.live.session import Snapshot
from capture.live.timeline import TimelineEntry
from capture.live.trials import SubjectInfo
from capture.recording import topics as T
from capture.recording.lineage import derivation
from devices.base import DeviceEvent, DeviceState, DeviceStatus
from devices.clock import now_ns
from devices.files import check_replaceable
from devices.frames import MODES
from inference.fusion import FusionOutput
from inference.preprocess import STALE_ORIENTATION

log = logging.getLogger(__name__)

TIMELINE_S = 20.0
PROFILE_POINTS = 600  # per frame kept for the profile plot (the display is ~100 dots wide)
CORRECTION = "correction"  # capture.recording.reader.CORRECTION


def _mode_index(mode) -> int:
    return MODES.index(mode) if mode in MODES else -1


@dataclasses.dataclass
class _Frames:
    """Everything shown per frame, as arrays in frame order (frames with a CNN output)."""

    index: np.ndarray  # (N,) frame numbers
    time_ns: np.ndarray  # (N,) sample time
    host_ns: np.ndarray  # (N,) receive time
    probabilities: np.ndarray  # (N, 5)
    cnn: np.ndarray  # (N,) mode index
    fused: np.ndarray  # (N,) fused decision recorded for the frame, -1 none
    voted: np.ndarray  # (N,)
    fused_shown: np.ndarray  # (N,) latest fused decision produced at or before the frame
    truth: np.ndarray  # (N,) simulator's mode, -1 none
    images: dict[int, np.ndarray]  # frame -> packed bits of the 100 x 100 image
    profiles: dict[int, np.ndarray]  # frame -> (M, 2) float16
    flags: dict[int, str]
    features: dict[int, dict]


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
        self.metadata: dict = {}
        self.subject_info: SubjectInfo | None = None
        self.saved_path: Path | None = None
        self.trial_notice = ""  # a replay records no trial
        self.trial: SubjectInfo | None = None
        self.alarms = None
        self._camera = self._imu = None
        self._changes_cache: tuple[list, np.ndarray] | None = None
        self._unsaved = False

    # ---- life cycle -------------------------------------------------------------------

    def start(self) -> None:
        """Read the recording into memory (images packed, profiles decimated)."""
        from capture.recording.reader import open_recording

        rec = open_recording(self.path)
        self.metadata = rec.metadata
        self.frames = self._load(rec)
        # stale frames up to each frame, for the devices panel's count
        self._stale_upto = np.cumsum(
            [self.frames.flags.get(int(i)) == STALE_ORIENTATION for i in self.frames.index]
        )
        n = len(self.frames.index)
        if n == 0:
            raise CaptureError(f"{self.path}: no classified frames to replay")
        self._start_ns = int(self.frames.time_ns[0])
        self.duration_s = (int(self.frames.time_ns[-1]) - self._start_ns) * 1e-9
        self._camera, self._imu = self._device_status(rec, n)
        self.subject_info = _subject_from_metadata(rec.metadata.get("session", {}))
        self._anchor_wall = self._clock()
        self.playing = self._play_on_start

    def _load(self, rec) -> _Frames:
        cnn, fused, voted, produced, truth, undecided = {}, {}, {}, {}, {}, {}
        images, profiles, flags, features = {}, {}, {}, {}
        wanted = [
            T.CNN,
            T.FUSED,
            T.TRUTH,
            T.LABELS,
            T.EVENTS,
            T.BINARY_IMAGE,
            T.CLOUD,
            T.PREPROCESS,
            T.FEATURES,
        ]
        for m in rec.messages(wanted):
            d = m.data
            if m.topic == T.CNN:
                cnn[int(d["frame_index"])] = (int(d["time_ns"]), m.log_time_ns, d["probabilities"])
            elif m.topic == T.FUSED:
                decision = _mode_index(d.get("decision"))
                fused[int(d["frame_index"])] = decision
                produced[int(d.get("source_frame_index", d["frame_index"]))] = decision
                if d.get("voted") is not None and d.get("voted_frame_index") is not None:
                    voted[int(d["voted_frame_index"])] = _mode_index(d["voted"])
            elif m.topic == T.TRUTH:
                truth[int(d["frame_index"])] = _mode_index(d.get("mode"))
            elif m.topic == T.LABELS:
                self.original_labels.append(
                    (int(d["time_ns"]), d.get("mode", ""), d.get("source", ""))
                )
            elif m.topic == T.EVENTS:
                self.events.append(
                    DeviceEvent(
                        int(d["time_ns"]),
                        d.get("device", ""),
                        d.get("kind", ""),
                        d.get("message", ""),
                        d.get("details") or {},
                    )
                )
            elif m.topic == T.BINARY_IMAGE:
                images[m.sequence] = np.packbits(np.asarray(m.data) > 0)
            elif m.topic == T.CLOUD:
                cloud = np.asarray(m.data)
                if len(cloud) > PROFILE_POINTS:
                    cloud = cloud[np.linspace(0, len(cloud) - 1, PROFILE_POINTS).astype(int)]
                profiles[m.sequence] = cloud[:, [0, 2]].astype(np.float16)  # forward, height
            elif m.topic == T.PREPROCESS:
                flags[int(d["frame_index"])] = d.get("flag", "")
                if d.get("flag") == STALE_ORIENTATION:  # a frame left without a decision
                    undecided[int(d["frame_index"])] = (int(d["time_ns"]), m.log_time_ns, None)
            elif m.topic == T.FEATURES:
                features[int(d["frame_index"])] = {
                    k: v
                    for k, v in d.items()
                    if k not in ("frame_index", "time_ns") and not isinstance(v, (list, dict))
                }
        self.original_labels.sort(key=lambda c: c[0])
        self.events.sort(key=lambda e: e.time_ns)
        cnn = {**undecided, **cnn}  # stale frames are shown too, as undecided
        index = np.array(sorted(cnn), dtype=np.int64)
        probs = np.array(
            [[np.nan if p is None else p for p in cnn[i][2] or [None] * len(MODES)] for i in index],
            dtype=np.float64,
        ).reshape(-1, len(MODES))
        shown = np.full(len(index), -1, dtype=int)
        last = -1
        for k, i in enumerate(index):  # what the big display showed when frame i was processed
            last = produced.get(int(i), last)
            shown[k] = last
        return _Frames(
            index=index,
            time_ns=np.array([cnn[i][0] for i in index], dtype=np.int64),
            host_ns=np.array([cnn[i][1] for i in index], dtype=np.int64),
            probabilities=probs,
            cnn=np.array(
                [int(np.nanargmax(p)) if np.isfinite(p).any() else -1 for p in probs], dtype=int
            ),
            fused=np.array([fused.get(int(i), -1) for i in index], dtype=int),
            voted=np.array([voted.get(int(i), -1) for i in index], dtype=int),
            fused_shown=shown,
            truth=np.array([truth.get(int(i), -1) for i in index], dtype=int),
            images=images,
            profiles=profiles,
            flags=flags,
            features=features,
        )

    def _device_status(self, rec, frames: int) -> tuple[DeviceStatus, DeviceStatus]:
        devices = self.metadata.get("devices", {})
        seconds = max(rec.duration_s, 1e-9)
        imu_count = rec.topics[T.IMU].count if T.IMU in rec.topics else 0
        name = self.path.name
        camera = DeviceStatus(
            backend=f"replay of {devices.get('camera_backend', '?')}",
            state=DeviceState.OK,
            message=name,
            configured_rate_hz=float(devices.get("camera_fps") or 0),
            measured_rate_hz=frames / seconds,
            delivered=frames,
        )
        imu = DeviceStatus(
            backend=f"replay of {devices.get('imu_backend', '?')}",
            state=DeviceState.OK,
            configured_rate_hz=float(devices.get("imu_rate_hz") or 0),
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
            pos += (self._clock() - self._anchor_wall) * 1e-9
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
        t = self._start_ns + int(round(pos * 1e9))
        k = int(np.searchsorted(self.frames.time_ns, t, side="right")) - 1
        return max(k, 0), t

    # ---- labels -----------------------------------------------------------------------

    def label_changes(self) -> list[tuple[int, str, str]]:
        """The reference: the original changes with their undos applied (capture.recording.reader
        effective_changes), and the corrections, in time order (corrections last on ties)."""
        from capture.recording.reader import effective_changes

        merged = self.original_labels + [(c.time_ns, c.mode, CORRECTION) for c in self.corrections]
        return effective_changes(merged)

    def _labels_at(self, times_ns: np.ndarray) -> np.ndarray:
        from capture.recording.reader import labels_at

        return labels_at(times_ns, self.label_changes())

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
        """The true mode from the replay position on (until the next change)."""
        if mode not in MODES:
            raise CaptureError(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
        if time_ns is None:
            _, time_ns = self._cursor()
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
            quaternion=None,
            image=image,
            cloud=np.zeros((0, 3), np.float32),
            profile=f.profiles.get(i, np.zeros((0, 2), np.float16)).astype(np.float32),
            flag=f.flags.get(i, ""),
            probabilities=f.probabilities[k],
            cnn_decision=int(f.cnn[k]),
            # the decision the display showed then (the frame it decided is not kept)
            fused=FusionOutput(frame=None, decision=shown) if shown >= 0 else None,
            features=f.features.get(i, {}),
        )
        lo = int(np.searchsorted(f.time_ns, t - int(TIMELINE_S * 1e9), side="left"))
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
            stale_frames=int(self._stale_upto[k]),
        )


def _subject_from_metadata(session: dict) -> SubjectInfo | None:
    """The recording's session metadata back into a SubjectInfo (best effort, for display)."""
    if not session:
        return None
    kwargs = {}
    for f in dataclasses.fields(SubjectInfo):
        raw = session.get(f.name)
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
    corrections to /labels and the markers to /events.

    A raw copy rather than capture.recording.writer.Recorder: the Recorder re-encodes (depth from
    xyz with rays rebuilt from intrinsics, clouds decimated again) and drops what its
    bounded queue cannot take; a copy keeps every recorded byte as it was.
    """
    from mcap.writer import CompressionType, Writer

    from capture.recording.reader import _iter_raw, open_recording

    original, target = Path(original), Path(target)
    if target.resolve() == original.resolve():
        raise CaptureError("the corrected file must be a new file: the original is never modified")
    check_replaceable(target)
    rec = open_recording(original)
    tmp = target.with_name(f".{target.name}.partial")
    try:
        with open(tmp, "wb") as out:  # a leftover partial file of ours is replaced
            writer = Writer(out, compression=CompressionType.ZSTD)
            writer.start(profile="", library=rec.library or "walkcap")
            # The copy is a new recording (its own id) derived from the original; values
            # are written as JSON, whatever the original held.
            copy_id = str(uuid.uuid4())
            for name, values in rec.metadata_records:
                if name == "recording":
                    values = {**values, "id": copy_id, T.METADATA_VALUES_KEY: T.METADATA_VALUES}
                if name != "derivation":
                    writer.add_metadata(name, T.encode_metadata(values))
            writer.add_metadata(
                "derivation",
                T.encode_metadata(
                    derivation(rec, copy_id, "corrected", f"{len(corrections)} label correction(s)")
                ),
            )
            writer.add_metadata(
                "corrections",
                T.encode_metadata(
                    {
                        "source": original.name,
                        "source_size": rec.size,
                        "written": dt.datetime.now().isoformat(timespec="seconds"),
                        "labels": [[c.time_ns, c.mode] for c in corrections],
                        "markers": len(markers),
                        "rule": "label changes apply from their time until the next; "
                        f"corrections have source '{CORRECTION}'",
                    }
                ),
            )
            t0 = rec.start_ns or 0
            for name, data in rec.attachments.items():
                media = (
                    "application/x-npy"
                    if name.endswith(".npy")
                    else "application/json"
                    if name.endswith(".json")
                    else "application/octet-stream"
                )
                writer.add_attachment(t0, t0, name, media, data)
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}  # original channel id -> new id
            by_topic: dict[str, int] = {}
            for schema, channel, message in _iter_raw(original, rec.complete, None):
                cid = channels.get(channel.id)
                if cid is None:
                    sid = 0
                    if schema is not None:
                        sid = schemas.get(schema.id) or writer.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                        schemas[schema.id] = sid
                    cid = writer.register_channel(
                        channel.topic, channel.message_encoding, sid, dict(channel.metadata)
                    )
                    channels[channel.id] = cid
                    by_topic.setdefault(channel.topic, cid)
                writer.add_message(
                    cid, message.log_time, message.data, message.publish_time, message.sequence
                )
            extra = [
                (T.LABELS, c.time_ns, T.label_json(c.time_ns, c.mode, CORRECTION))
                for c in corrections
            ]
            extra += [(T.EVENTS, e.time_ns, T.event_json(e)) for e in markers]
            for topic, t, entry in sorted(extra, key=lambda x: x[1]):
                cid = by_topic.get(topic) or _json_channel(writer, topic, by_topic)
                writer.add_message(cid, t, T.encode_json(entry), t, 0)
            writer.finish()
            out.flush()
            os.fsync(out.fileno())
        os.link(tmp, target)  # fails if the target exists: never overwrite
    except FileExistsError:
        raise CaptureError(f"{target} exists: a recording is never overwritten") from None
    except OSError as e:
        raise CaptureError(f"cannot write {target}: {e.strerror or e}") from None
    finally:
        try:
            tmp.unlink()
        except OSError:
            pass
    return target


def _json_channel(writer, topic: str, by_topic: dict[str, int]) -> int:
    """A channel for `topic` in the new file when the original had none."""
    spec = T.topic_spec(topic)
    sid = writer.register_schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
    by_topic[topic] = writer.register_channel(
        topic, spec.message_encoding, sid, {"description": T.DESCRIPTIONS[topic]}
    )
    return by_topic[topic]


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
