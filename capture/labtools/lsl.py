"""Lab Streaming Layer: walkcap's streams out, other devices' streams into the recording.

Outlets (`LslOutlets`, a session tap): the IMU at its device rate (quaternion,
acceleration, rate of turn), the classifier per frame (probabilities, CNN decision, fused
and voted decisions with the frames they refer to) and the operator's labels and markers
as a string marker stream. Each sample is stamped with its sample time (the IMU's
device-corrected time, the frame's exposure time) on LSL's clock, so LabRecorder's XDF
lines walkcap up with EMG, motion capture and force plates. Source ids are stable for a
device, so a restarted session resumes the same stream in LabRecorder.

Inlets (`LslInlets`): named streams of other devices recorded into the MCAP file while a
trial records, as sent: marker streams into /events (every channel), numeric streams into
`/lsl/<name>` (whole numbers exact, infinities apart from NaN), one message per pulled
chunk, times mapped onto the session clock with LSL's time correction (the offset and its
uncertainty go into every message). A stream that disappears is an event and a gap;
walkcap looks for it again at once and carries on.

liblsl logs to stderr, where the terminal UI draws, and its lines quote what the network
says (stream names, hosts): walkcap tells it to log warnings and errors to a file of its
own instead, `~/.cache/walkcap/liblsl.log`, and nothing to the terminal.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import logging
import os
import re
import socket
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from capture.errors import CaptureError
from capture.labtools.safetext import escape
from capture.recording.sink import Sink
from devices import clock
from devices.base import DeviceEvent
from devices.clock import now_ns
from devices.frames import MODES

log = logging.getLogger(__name__)

IMU_CHANNELS = (
    ("qw", "normalized", "Orientation"),
    ("qx", "normalized", "Orientation"),
    ("qy", "normalized", "Orientation"),
    ("qz", "normalized", "Orientation"),
    ("ax", "m/s^2", "Acceleration"),
    ("ay", "m/s^2", "Acceleration"),
    ("az", "m/s^2", "Acceleration"),
    ("gx", "rad/s", "AngularVelocity"),
    ("gy", "rad/s", "AngularVelocity"),
    ("gz", "rad/s", "AngularVelocity"),
)
TERRAIN_CHANNELS = (
    ("frame_index", "count", "Index"),
    *((f"p_{m}", "probability", "Probability") for m in MODES),
    ("cnn_decision", "mode index", "Decision"),
    ("fused_frame_index", "count", "Index"),
    ("fused_decision", "mode index", "Decision"),
    ("voted_frame_index", "count", "Index"),
    ("voted_decision", "mode index", "Decision"),
)
NO_DECISION = -1.0  # a decision channel before the first decision (and NaN frame indices)
TIME_CORRECTION_EVERY_S = 5.0
RESOLVE_TIMEOUT_S = 0.2  # one resolve while a stream is missing; the next follows at once
OPEN_TIMEOUT_S = 1.0
SILENT_CHECK_S = 0.5  # a stream this long without a sample: does its outlet still answer?
SILENT_RESOLVE_S = 0.3

_lsl_lock = threading.Lock()
_lsl = None


def pylsl():
    """pylsl, imported on first use with liblsl told to keep quiet (errors only)."""
    global _lsl
    with _lsl_lock:
        if _lsl is None:
            try:
                import pylsl as module
            except (ImportError, OSError, RuntimeError) as e:
                raise CaptureError(f"LSL is not available: {e} (pip install pylsl)") from None
            quiet_liblsl(module, liblsl_log_path())
            _lsl = module
    return _lsl


LIBLSL_LOG_LEVEL = -1  # liblsl's warnings and errors (loguru: -2 errors, 0 info)


def liblsl_log_path() -> str:
    return os.path.join(os.path.expanduser("~"), ".cache", "walkcap", "liblsl.log")


def quiet_liblsl(module, path: str, level: int = LIBLSL_LOG_LEVEL) -> None:
    """liblsl's log into `path`, none of it on the terminal. liblsl turns its stderr off
    only once its file is open, and says so on stderr first: that one line goes into the
    file too, fd 2 pointed there for the instant liblsl reads its configuration."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        module.set_config_content(f"[log]\nlevel = {level}\nfile = {path}\n")
    except Exception:  # already initialised, or no folder: errors only, as before
        with contextlib.suppress(Exception):
            module.set_config_content("[log]\nlevel = -2\n")
        return
    with contextlib.suppress(OSError), _stderr_into(path):
        module.protocol_version()  # liblsl reads its configuration now


@contextlib.contextmanager
def _stderr_into(path: str):
    """fd 2 appended to `path` for the duration (Python's and C's stderr alike)."""
    with contextlib.suppress(Exception):
        sys.stderr.flush()
    saved = os.dup(2)
    target = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    try:
        os.dup2(target, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(target)


def lsl_offset_s() -> float:
    """LSL's clock minus the session clock, seconds (both monotonic; the offset is fixed)."""
    lsl = pylsl()
    best = None
    for _ in range(5):  # the reading bracketed most tightly by two session-clock reads
        a = now_ns()
        t = lsl.local_clock()
        b = now_ns()
        if best is None or b - a < best[0]:
            best = (b - a, t - (a + b) * 0.5e-9)
    return best[1]


def _describe(info, channels, device: dict) -> None:
    """XDF's channel convention (desc/channels/channel: label, unit, type) and the device."""
    desc = info.desc()
    chans = desc.append_child("channels")
    for label, unit, kind in channels:
        ch = chans.append_child("channel")
        ch.append_child_value("label", label)
        ch.append_child_value("unit", unit)
        ch.append_child_value("type", kind)
    acq = desc.append_child("acquisition")
    acq.append_child_value("manufacturer", "walkcap")
    for key, value in device.items():
        acq.append_child_value(key, str(value))


def source_id(kind: str, device_id: str = "") -> str:
    """Stable per device and host: LabRecorder resumes a restarted session's stream."""
    ident = re.sub(r"[^A-Za-z0-9_.-]", "_", str(device_id)) if device_id else "default"
    return f"walkcap-{socket.gethostname()}-{kind}-{ident}"


class LslOutlets(Sink):
    """A session tap (Session.add_tap) publishing walkcap's streams as LSL outlets."""

    def __init__(
        self,
        *,
        imu_rate_hz: float,
        camera_fps: float,
        imu_id: str = "",
        camera_id: str = "",
        name: str = "walkcap",
    ) -> None:
        lsl = pylsl()
        self.offset_s = lsl_offset_s()
        imu = lsl.StreamInfo(
            f"{name} IMU",
            "IMU",
            len(IMU_CHANNELS),
            float(imu_rate_hz),
            lsl.cf_float32,
            source_id("imu", imu_id),
        )
        _describe(imu, IMU_CHANNELS, {"device": "Xsens MTi", "device_id": imu_id})
        terrain = lsl.StreamInfo(
            f"{name} Terrain",
            "Classifier",
            len(TERRAIN_CHANNELS),
            float(camera_fps),
            lsl.cf_double64,
            source_id("terrain", camera_id),
        )
        _describe(
            terrain,
            TERRAIN_CHANNELS,
            {"device": "pmd pico flexx", "device_id": camera_id, "modes": " ".join(MODES)},
        )
        markers = lsl.StreamInfo(
            f"{name} Markers",
            "Markers",
            1,
            lsl.IRREGULAR_RATE,
            lsl.cf_string,
            source_id("markers", camera_id or imu_id),
        )
        _describe(markers, (("marker", "text", "Marker"),), {"content": "labels and markers"})
        self.imu = lsl.StreamOutlet(imu)
        self.terrain = lsl.StreamOutlet(terrain)
        self.markers = lsl.StreamOutlet(markers)
        self.sent = {"imu": 0, "terrain": 0, "markers": 0}
        self.errors = 0

    def _lsl_time(self, time_ns: int) -> float:
        return clock.seconds(time_ns) + self.offset_s

    def _push(self, stream: str, outlet, values, time_ns: int) -> None:
        try:
            outlet.push_sample(values, self._lsl_time(time_ns))
            self.sent[stream] += 1
        except Exception as e:  # a peer's trouble never reaches the session
            self.errors += 1
            if self.errors == 1:
                log.warning("LSL %s outlet: %s", stream, e)

    # ---- the session's data that an outlet carries (Sink); the rest it ignores --------------

    def write_imu(self, sample) -> None:
        if sample.quaternion is None:
            return
        values = np.full(len(IMU_CHANNELS), np.nan, dtype=np.float32)
        values[0:4] = sample.quaternion
        if sample.acceleration is not None:
            values[4:7] = sample.acceleration
        if sample.rate_of_turn is not None:
            values[7:10] = sample.rate_of_turn
        t = sample.time_ns if sample.time_ns is not None else sample.host_time_ns
        self._push("imu", self.imu, values.tolist(), t)

    def write_inference(self, frame_index, time_ns, log_time_ns, probabilities, fused) -> None:
        fused = fused or {}

        def mode(name) -> float:
            return float(MODES.index(name)) if name in MODES else NO_DECISION

        def index(value) -> float:
            return float(value) if value is not None else NO_DECISION

        probs = np.asarray(probabilities, dtype=np.float64).ravel()
        values = [
            float(frame_index),
            *probs.tolist(),
            float(np.argmax(probs)) if np.all(np.isfinite(probs)) else NO_DECISION,
            index(fused.get("frame_index")),
            mode(fused.get("decision")),
            index(fused.get("voted_frame_index")),
            mode(fused.get("voted")),
        ]
        self._push("terrain", self.terrain, values, time_ns)

    def write_label(self, time_ns: int, mode: str, source: str) -> None:
        self._push("markers", self.markers, [f"label {mode or '-'} ({source})"], time_ns)

    def write_event(self, event) -> None:
        if isinstance(event, dict):
            device, kind = event.get("device", ""), event.get("kind", "")
            message, t = event.get("message", ""), event.get("time_ns") or now_ns()
        else:
            device, kind, message, t = event.device, event.kind, event.message, event.time_ns
        if device == "operator":  # markers and notes; device faults stay in the recording
            self._push("markers", self.markers, [f"{kind}: {message}"], t)

    def close(self) -> None:
        self.imu = self.terrain = self.markers = None


class _TimeCorrection:
    """liblsl's time correction with its uncertainty (lsl_time_correction_ex)."""

    def __init__(self, lsl, inlet) -> None:
        self._lib = lsl.lib
        self._inlet = inlet
        self._ex = getattr(self._lib, "lsl_time_correction_ex", None)
        if self._ex is not None:
            self._ex.restype = ctypes.c_double
            self._ex.argtypes = [
                ctypes.c_void_p,
                ctypes.POINTER(ctypes.c_double),
                ctypes.POINTER(ctypes.c_double),
                ctypes.c_double,
                ctypes.POINTER(ctypes.c_int32),
            ]

    def __call__(self, timeout: float = 2.0) -> tuple[float, float]:
        if self._ex is None:
            return float(self._inlet.time_correction(timeout)), float("nan")
        remote, uncertainty, err = ctypes.c_double(), ctypes.c_double(), ctypes.c_int32()
        offset = self._ex(
            self._inlet.obj,
            ctypes.byref(remote),
            ctypes.byref(uncertainty),
            timeout,
            ctypes.byref(err),
        )
        if err.value:
            raise TimeoutError(f"LSL time correction failed ({err.value})")
        return float(offset), float(uncertainty.value)


def chunk_schema(name: str, channels: list[str], integer: bool = False) -> dict:
    """JSON Schema of a recorded numeric LSL stream's messages (one per pulled chunk)."""
    if integer:
        value = {"type": "integer"}
        kinds = "whole numbers, exact (int8 to int64 streams)"
    else:
        value = {"anyOf": [{"type": "number"}, {"type": "null"}, {"enum": ["inf", "-inf"]}]}
        kinds = 'numbers; NaN as null, infinities as "inf" and "-inf"'
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "walkcap.LslChunk",
        "description": f"LSL stream {name!r}: samples of one pulled chunk. time_ns on the "
        f"session clock (LSL time + time correction; null for a sample time outside it); "
        f"values ({kinds}) in the channel order {', '.join(channels) or '(unnamed)'}.",
        "type": "object",
        "properties": {
            "stream": {"type": "string"},
            "time_ns": {"type": "array", "items": {"type": ["integer", "null"]}},
            "lsl_time": {"type": "array", "items": {"type": "number"}},
            "values": {"type": "array", "items": {"type": "array", "items": value}},
            "channels": {"type": "array", "items": {"type": "string"}},
            "time_correction_s": {"type": "number"},
            "time_correction_uncertainty_s": {"type": ["number", "null"]},
        },
        "required": ["stream", "time_ns", "lsl_time", "values", "time_correction_s"],
    }


def topic_for(name: str) -> str:
    """The recording's topic of LSL stream `name`: its name where that is letters, digits
    and '_'; otherwise those, and a short hash of the exact name, so that names differing
    only in punctuation (EMG-1, EMG_1, EMG 1) have topics of their own."""
    plain = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")
    if plain == name:
        return f"/lsl/{name}"
    digest = hashlib.blake2s(name.encode("utf-8"), digest_size=4).hexdigest()
    return f"/lsl/{plain}_{digest}" if plain else f"/lsl/_{digest}"


INTEGER_FORMATS = ("cf_int8", "cf_int16", "cf_int32", "cf_int64")
_INT64_NS = 2**63  # sample times on the session clock fit int64 nanoseconds, from 0


def chunk_values(samples, integer: bool) -> list:
    """A pulled chunk's values as JSON keeps them, type for type: whole numbers exact;
    NaN as null and the infinities as "inf" / "-inf" (np.asarray(values, float) reads
    each back)."""
    if integer:
        return np.asarray(samples, dtype=np.int64).tolist()
    values = np.asarray(samples, dtype=np.float64)
    finite = np.isfinite(values)
    if finite.all():
        return values.tolist()
    out = values.astype(object)
    out[np.isnan(values)] = None
    out[np.isposinf(values)] = "inf"
    out[np.isneginf(values)] = "-inf"
    return out.tolist()


def session_times(lsl_times: np.ndarray, offset_s: float) -> list[int | None]:
    """LSL times (already time-corrected) on the session clock, ns; None for one that
    falls outside it (before 0, beyond int64, not finite)."""
    ns = (lsl_times - offset_s) * 1e9
    ok = np.isfinite(ns) & (ns >= 0) & (ns < _INT64_NS)
    rounded = np.round(np.where(ok, ns, 0)).astype(np.int64).tolist()
    return [t if good else None for t, good in zip(rounded, ok.tolist())]


class LslInlets:
    """Record named LSL streams into whichever recording is open.

    `recorder()` returns the session's recorder (None between trials); `on_event(event)`
    takes DeviceEvents (found, lost) for the screen and the file.

    A stream that is lost is looked for again at once (a resolve every RESOLVE_TIMEOUT_S),
    so one that comes back, under a new source id too, is recorded again within about a
    third of a second of its return. One that falls silent for SILENT_CHECK_S is asked for:
    when its outlet no longer answers and another of that name does, walkcap records that
    one (an outlet that hangs sends no "lost").
    """

    def __init__(
        self,
        names: list[str],
        recorder: Callable[[], object | None],
        on_event: Callable[[DeviceEvent], None],
    ) -> None:
        self.names = list(dict.fromkeys(names))
        self.topics = {name: topic_for(name) for name in self.names}
        if len(set(self.topics.values())) < len(self.topics):
            raise CaptureError(f"LSL streams {self.names} share a topic name: rename one")
        self._recorder = recorder
        self._on_event = on_event
        self._halt = threading.Event()
        self._threads: list[threading.Thread] = []
        self.received: dict[str, int] = dict.fromkeys(self.names, 0)
        self.state: dict[str, str] = dict.fromkeys(self.names, "looking")
        self.bad_times: dict[str, int] = dict.fromkeys(self.names, 0)  # outside the clock

    def start(self) -> None:
        lsl = pylsl()
        self._offset_s = lsl_offset_s()
        for name in self.names:
            t = threading.Thread(
                target=self._run, args=(lsl, name), name=f"walkcap-lsl-{name}", daemon=True
            )
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        self._halt.set()
        for t in self._threads:
            t.join(timeout=3.0)
        self._threads.clear()

    def _event(self, stream: str, kind: str, message: str, details: dict | None = None) -> None:
        self._on_event(DeviceEvent(now_ns(), f"lsl:{stream}", kind, message, details or {}))

    def _run(self, lsl, name: str) -> None:
        gone = ""  # the uid of the outlet last recorded, once it is lost
        while not self._halt.is_set():
            try:  # the resolve is the wait: no pause between two
                found = lsl.resolve_byprop("name", name, 1, RESOLVE_TIMEOUT_S)
            except Exception as e:
                log.warning("LSL resolve %s: %s", name, escape(str(e)))
                found = []
                self._halt.wait(RESOLVE_TIMEOUT_S)
            found = [f for f in found if f.uid() != gone] or found
            if not found:
                continue
            try:
                gone = self._record(lsl, name, found[0])
            except Exception as e:  # a peer's trouble is an event, never the session's end
                log.warning("LSL stream %s: %s", name, escape(str(e)))
                self._event(name, "error", f"LSL stream {name}: {escape(str(e))}")
                gone = found[0].uid()
                self._halt.wait(RESOLVE_TIMEOUT_S)
            self.state[name] = "looking"

    def _replaced(self, lsl, name: str, uid: str) -> bool:
        """Whether stream `uid` no longer answers while another of its name does."""
        try:
            found = lsl.resolve_byprop("name", name, 0, SILENT_RESOLVE_S)
        except Exception:
            return False
        uids = {f.uid() for f in found}
        return bool(uids) and uid not in uids

    def _record(self, lsl, name: str, info) -> str:
        """Record stream `info` until it is lost or replaced; returns its uid."""
        inlet = lsl.StreamInlet(info, max_buflen=60, recover=False)
        inlet.open_stream(timeout=OPEN_TIMEOUT_S)
        full = inlet.info(timeout=OPEN_TIMEOUT_S)
        uid = full.uid()
        channels = _channel_labels(full)
        fmt = full.channel_format()
        is_marker = fmt == lsl.cf_string
        integer = fmt in {getattr(lsl, f) for f in INTEGER_FORMATS if hasattr(lsl, f)}
        stream = {
            "name": full.name(),
            "type": full.type(),
            "channel_count": full.channel_count(),
            "nominal_srate": full.nominal_srate(),
            "source_id": full.source_id(),
            "hostname": full.hostname(),
        }
        correct = _TimeCorrection(lsl, inlet)
        offset, uncertainty = correct(2.0)
        next_correction = time.monotonic() + TIME_CORRECTION_EVERY_S
        self.state[name] = "recording"
        self._event(
            name,
            "lsl_found",
            f"LSL stream {name} ({escape(stream['type'])}, {stream['channel_count']} ch, "
            f"{stream['nominal_srate']:g} Hz)",
            {
                **stream,
                "time_correction_s": offset,
                "time_correction_uncertainty_s": uncertainty,
            },
        )
        declared_on = None
        topic = self.topics[name]
        last_ns = None
        heard = time.monotonic()
        while not self._halt.is_set():
            try:
                samples, stamps = inlet.pull_chunk(timeout=0.2, max_samples=4096)
                if time.monotonic() >= next_correction:
                    offset, uncertainty = correct(0.5)
                    next_correction = time.monotonic() + TIME_CORRECTION_EVERY_S
            except RuntimeError as e:  # pylsl's LostError: the outlet went away
                since = f" after {clock.seconds(now_ns() - last_ns):.2f} s" if last_ns else ""
                self._event(name, "lsl_lost", f"LSL stream {name} lost{since}: {e}")
                inlet.close_stream()
                return uid
            if not stamps:
                if time.monotonic() - heard >= SILENT_CHECK_S:
                    heard = time.monotonic()
                    if self._replaced(lsl, name, uid):
                        self._event(
                            name,
                            "lsl_lost",
                            f"LSL stream {name} lost: its outlet no longer answers, "
                            f"another of that name does",
                        )
                        inlet.close_stream()
                        return uid
                continue
            heard = time.monotonic()
            lsl_times = np.asarray(stamps, dtype=np.float64) + offset
            times = session_times(lsl_times, self._offset_s)
            self.received[name] += len(stamps)
            valid = [t for t in times if t is not None]
            if valid:
                last_ns = valid[-1]
            if len(valid) < len(times):
                bad = [lt for lt, t in zip(lsl_times.tolist(), times) if t is None]
                self._bad_times(name, bad)
            rec = self._recorder()
            if rec is None:
                continue
            received_ns = now_ns()
            if is_marker:
                for value, t, lsl_t in zip(samples, times, lsl_times.tolist()):
                    self._marker(rec, name, channels, value, t, lsl_t, received_ns)
                continue
            if declared_on is not rec:
                description = f"LSL stream {escape(name)}"
                rec.declare_topic(topic, chunk_schema(name, channels, integer), description)
                declared_on = rec
            rec.write_message(
                topic,
                valid[0] if valid else received_ns,
                received_ns,
                {
                    "stream": name,
                    "time_ns": times,
                    "lsl_time": np.asarray(stamps, dtype=np.float64).tolist(),
                    "values": chunk_values(samples, integer),
                    "channels": channels,
                    "time_correction_s": offset,
                    "time_correction_uncertainty_s": uncertainty,
                },
            )
        return uid

    def _marker(self, rec, name, channels, value, t, lsl_t, received_ns) -> None:
        """One marker sample as an event: every channel (the first is the message)."""
        values = [str(v) for v in value] if isinstance(value, (list, tuple)) else [str(value)]
        details: dict = {"stream": name}
        if len(values) > 1:
            details["values"] = values
            if channels:
                details["channels"] = channels
        if t is None:  # a sample time outside the session clock: its receipt, and its LSL time
            details["lsl_time"] = lsl_t
            t = received_ns
        rec.write_event(
            {
                "time_ns": t,
                "device": f"lsl:{name}",
                "kind": "marker",
                "message": values[0] if len(values) == 1 else " | ".join(values),
                "details": details,
            }
        )

    def _bad_times(self, name: str, lsl_times: list[float]) -> None:
        first = self.bad_times[name] == 0
        self.bad_times[name] += len(lsl_times)
        if first:  # once a stream: its samples carry time_ns null, their lsl_time as sent
            self._event(
                name,
                "lsl_bad_time",
                f"LSL stream {name}: a sample time outside the session clock "
                f"({lsl_times[0]:.6g} s); such samples are recorded without time_ns",
                {"count": len(lsl_times), "lsl_time": lsl_times[0]},
            )


def _channel_labels(info) -> list[str]:
    labels = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty():
        labels.append(ch.child_value("label"))
        ch = ch.next_sibling()
    return labels if len(labels) == info.channel_count() else []
