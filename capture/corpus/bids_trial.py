"""One trial as BIDS-Motion files: the IMU as a tracking system, its events, walkcap's
per-frame results. Pure: tables in (capture.corpus.export.tables), text and JSON out;
capture.corpus.bids lays them out and writes them.

The motion file's time: its first row is the trial's first IMU sample (the `acq_time` of
scans.tsv); the LATENCY channel is each sample's time from it, in seconds, exact to the ns
(SampleTimeFine on the session clock). Events' onsets and the frames' onsets count from the
same instant. The MTi samples at a fixed rate: a sample the device produced and the file
lacks (a gap in the packet counter, capture.recording.gaps) is an all-`n/a` row in its
place, so row k is the device's k-th sample; every recorded sample is a row, none is
made up.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from capture.recording.gaps import MODULUS, missing_between
from capture.recording.metadata import DevicesRecord, Metadata
from devices import clock
from devices.frames import MODE_NAMES, MODES

NA = "n/a"
TRACKSYS = "imu"
TRACKED_POINT = "thigh_imu"

# (name, component, type, units, reference frame, description, the imu table's column)
CHANNELS = (
    ("latency", NA, "LATENCY", "s", NA, "sample time from the first sample", None),
    ("acc_x", "x", "ACCEL", "m/s^2", "sensor", "acceleration", "acc_x"),
    ("acc_y", "y", "ACCEL", "m/s^2", "sensor", "acceleration", "acc_y"),
    ("acc_z", "z", "ACCEL", "m/s^2", "sensor", "acceleration", "acc_z"),
    ("gyr_x", "x", "GYRO", "rad/s", "sensor", "rate of turn", "gyr_x"),
    ("gyr_y", "y", "GYRO", "rad/s", "sensor", "rate of turn", "gyr_y"),
    ("gyr_z", "z", "GYRO", "rad/s", "sensor", "rate of turn", "gyr_z"),
    ("quat_w", "quat_w", "ORNT", NA, "enu", "orientation, sensor to ENU world", "qw"),
    ("quat_x", "quat_x", "ORNT", NA, "enu", "orientation, sensor to ENU world", "qx"),
    ("quat_y", "quat_y", "ORNT", NA, "enu", "orientation, sensor to ENU world", "qy"),
    ("quat_z", "quat_z", "ORNT", NA, "enu", "orientation, sensor to ENU world", "qz"),
    ("packet_counter", NA, "MISC", NA, NA, "the MTi's 16-bit packet counter", "packet_counter"),
    (
        "sample_time_fine",
        NA,
        "MISC",
        NA,
        NA,
        "the MTi's SampleTimeFine, 10 kHz ticks of its own clock",
        "sample_time_fine",
    ),
    ("status_word", NA, "MISC", NA, NA, "the MTi's status word", "status_word"),
)

REFERENCE_FRAMES = {
    "sensor": {
        "Description": "the MTi's own axes, fixed to the thigh: x forward, y left, z up "
        "when standing (acceleration includes gravity)",
        "SpatialAxes": "FLU",
        "RotationRule": "right-hand",
        "RotationOrder": "n/a",
    },
    "enu": {
        "Description": "East-North-Up world frame of the MTi's orientation filter (the "
        "quaternion rotates sensor axes into it; heading is not referenced to true north)",
        "RotationRule": "right-hand",
        "RotationOrder": "n/a",
    },
}


@dataclass
class MotionFile:
    rows: list[str]  # TSV lines, no header
    samples: int  # rows from recorded samples
    missing: int  # n/a rows: samples the device produced and the file lacks
    first_ns: int | None  # the first sample's time, session clock (the file's time zero)
    duration_s: float
    rate_hz: float | None = None  # nominal: the configured rate, else the median interval's


def _number(v) -> str:
    """A value as BIDS TSV text: n/a for missing, integers without a point, floats exact."""
    if v is None:
        return NA
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    try:
        f = float(v)
    except (TypeError, ValueError):
        return text(v)
    if math.isnan(f):
        return NA
    return repr(f)


def text(v) -> str:
    """Free text as one TSV cell: no tabs or line breaks; empty -> n/a."""
    s = "" if v is None else str(v)
    s = " ".join(s.replace("\t", " ").splitlines()).strip()
    return s or NA


def _value(v):
    """A pandas cell as a plain value (pd.NA -> None)."""
    try:
        if v is None or v is np.nan or (not isinstance(v, str) and bool(v != v)):
            return None
    except (TypeError, ValueError):
        return None
    return None if str(v) == "<NA>" else v


def seconds(ns: int) -> str:
    """Integer ns as decimal seconds, exact: -0.000001234 style, 9 digits."""
    sign = "-" if ns < 0 else ""
    q, r = divmod(abs(int(ns)), 1_000_000_000)
    return f"{sign}{q}.{r:09d}"


def motion_file(imu, rate_hz: float | None) -> MotionFile:
    """The motion.tsv rows from the export's imu table (one row per recorded sample,
    in file order), with an n/a row for each sample the device produced and the file lacks."""
    n = len(imu)
    if n == 0:
        return MotionFile([], 0, 0, None, 0.0, rate_hz)
    times = [int(t) for t in imu["time_ns"]]
    if not rate_hz and n > 1:  # a file without its configured rate: its median interval
        median = float(np.median(np.diff(np.array(times, dtype=np.int64))))
        rate_hz = round(1e9 / median, 3) if median > 0 else None
    counters = [_value(c) for c in imu["packet_counter"]]
    columns = [imu[c].tolist() if c is not None else None for *_, c in CHANNELS]
    period = 1.0 / rate_hz if rate_hz else 0.0
    first = times[0]
    rows: list[str] = []
    missing = 0
    blank = "\t".join([NA] * len(CHANNELS))
    for k in range(n):
        if k and period > 0 and counters[k] is not None and counters[k - 1] is not None:
            lost = missing_between(
                int(counters[k - 1]),
                int(counters[k]),
                times[k] - times[k - 1],
                period,
                MODULUS["imu"],
                own_clock=False,
            )
            rows += [blank] * lost
            missing += lost
        cells = [seconds(times[k] - first)]
        cells += [_number(_value(col[k])) for col in columns[1:]]
        rows.append("\t".join(cells))
    return MotionFile(rows, n, missing, first, clock.seconds(times[-1] - first), rate_hz)


def channels_tsv(placement: str) -> str:
    header = ["name", "component", "type", "tracked_point", "units", "placement"]
    header += ["reference_frame", "description"]
    lines = ["\t".join(header)]
    for name, component, kind, units, frame, description, _ in CHANNELS:
        cells = [name, component, kind, TRACKED_POINT, units, text(placement), frame, description]
        lines.append("\t".join(cells))
    return "\n".join(lines) + "\n"


def channels_json() -> dict:
    return {
        "reference_frame": {
            "Description": "the frame a channel's values are given in",
            "Levels": REFERENCE_FRAMES,
        },
        "placement": {"Description": "where the tracked point sits on the body"},
    }


def motion_json(meta: Metadata, study, condition: str, motion: MotionFile) -> dict:
    """The *_motion.json sidecar: the required and recommended keys from the recording's
    metadata (device, firmware, rates, missing samples) and the [study] section."""
    devices = meta.devices
    info = devices.imu_info or devices.imu_details or {}
    software = meta.software
    rate = motion.rate_hz
    counts = Counter(c[2] for c in CHANNELS)
    rows = motion.samples + motion.missing
    effective = (rows - 1) / motion.duration_s if rows > 1 and motion.duration_s > 0 else NA
    backend = str(devices.imu_backend if devices.has("imu_backend") else "")
    model = str(info.get("product_code") or "Xsens MTi")
    if backend == "mock":
        model += " (walkcap's emulated MTi)"
    out = {
        "TaskName": condition,
        "TaskDescription": "walking over level ground, stairs and ramps up and down "
        f"(condition {condition}), the operator keying the locomotion mode as it changes",
        "Instructions": study.instructions or None,
        "SamplingFrequency": rate if rate else NA,
        "SamplingFrequencyEffective": effective,
        "TrackingSystemName": f"Xsens {info.get('family') or 'MTi'} IMU on the "
        f"{study.imu_placement}",
        "Manufacturer": "Xsens",
        "ManufacturersModelName": model,
        "DeviceSerialNumber": str(info.get("device_id") or NA),
        "SoftwareVersions": f"firmware {info.get('firmware') or NA}; walkcap "
        f"{software.walkcap_version or NA}",
        "InstitutionName": study.institution_name or None,
        "InstitutionAddress": study.institution_address or None,
        "InstitutionalDepartmentName": study.institution_department or None,
        "RecordingDuration": round(motion.duration_s, 9),
        "RecordingType": "continuous",
        "MissingValues": NA,
        "SubjectArtefactDescription": NA,
        "TrackedPointsCount": 1,
        "MotionChannelCount": len(CHANNELS),
    }
    for kind in ("ACCEL", "ANGACCEL", "GYRO", "JNTANG", "LATENCY", "MAGN", "MISC", "ORNT"):
        out[f"{kind}ChannelCount"] = counts.get(kind, 0)
    out["POSChannelCount"] = counts.get("POS", 0)
    out["VELChannelCount"] = counts.get("VEL", 0)
    out["walkcap"] = {
        "missing_samples": motion.missing,
        "recorded_samples": motion.samples,
        "recording_id": meta.recording.id if meta.recording.has("id") else "",
        "time_zero": "the first IMU sample (SampleTimeFine on the session clock)",
    }
    return {k: v for k, v in out.items() if v is not None}


def configured_rate(devices: DevicesRecord) -> float | None:
    """The IMU's output rate the recording was made with ([imu] rate_hz), if it says."""
    return devices.rates_hz.get("imu")


# ---- events ---------------------------------------------------------------------------

EVENT_COLUMNS = (
    "onset",
    "duration",
    "trial_type",
    "mode",
    "source",
    "in_reference",
    "undone",
    "device",
    "kind",
    "message",
)


def events_rows(tables: dict, first_ns: int | None, end_ns: int | None) -> list:
    """The events.tsv rows (onset order): every label change with its audit trail, markers
    (their notes in message), device events, gait events."""
    t0 = first_ns if first_ns is not None else 0
    rows = []
    labels = tables["labels"]
    effective = [
        (int(t), m)
        for t, m, ref in zip(labels["time_ns"], labels["mode"], labels["in_reference"])
        if ref
    ]
    ends = {t: nxt for (t, _), (nxt, _) in zip(effective, effective[1:])}
    for t, mode, source, is_undo, undone, ref in zip(
        labels["time_ns"],
        labels["mode"],
        labels["source"],
        labels["is_undo"],
        labels["undone"],
        labels["in_reference"],
    ):
        t = int(t)
        if is_undo:
            kind = "undo"
        elif ref:
            kind = "mode"
        else:
            kind = "mode_undone" if undone else "mode_superseded"
        until = ends.get(t, end_ns) if ref else None
        duration = seconds(until - t) if until is not None and until >= t else NA
        rows.append(
            (
                t,
                [
                    seconds(t - t0),
                    duration,
                    kind,
                    text(mode),
                    text(source),
                    _bool(ref),
                    _bool(undone),
                    "simulator" if source == "simulator" else "operator",
                    "label",
                    NA,
                ],
            )
        )
    events = tables["events"]
    for t, device, kind, message in zip(
        events["time_ns"], events["device"], events["kind"], events["message"]
    ):
        t = int(t)
        trial_type = "marker" if kind == "marker" else "device_event"
        rows.append(
            (
                t,
                [
                    seconds(t - t0),
                    NA,
                    trial_type,
                    NA,
                    NA,
                    NA,
                    NA,
                    text(device),
                    text(kind),
                    text(message),
                ],
            )
        )
    gait = tables.get("gait")
    if gait is not None:  # heel contacts and toe offs: the detector's and the simulator's
        for t, event, source, mode in zip(
            gait["time_ns"], gait["event"], gait["source"], gait["mode"]
        ):
            t = int(t)
            cells = [seconds(t - t0), NA, text(event), text(mode), text(source)]
            rows.append((t, [*cells, NA, NA, text(source), "gait", NA]))
    rows.sort(key=lambda r: r[0])
    return ["\t".join(cells) for _, cells in rows]


def _bool(v) -> str:
    return "true" if bool(v) else "false"


def events_json() -> dict:
    modes = {m: MODE_NAMES.get(m, m) for m in MODES}
    return {
        # no stimuli: the participant walks a course; the operator keys what happens
        "StimulusPresentation": {
            "OperatingSystem": "n/a",
            "ScreenDistance": "n/a",
            "SoftwareName": "n/a",
            "Code": "n/a",
        },
        "onset": {
            "Description": "seconds from the first IMU sample (the motion file's first row)",
            "Units": "s",
        },
        "duration": {
            "Description": "for a mode in force: until the next change in force "
            "or the trial's end; n/a for instants",
            "Units": "s",
        },
        "trial_type": {
            "Description": "what the row records",
            "Levels": {
                "mode": "a label change in force (undos applied): the operator's locomotion "
                "mode from onset for duration",
                "mode_undone": "a label change a later undo took back (audit trail)",
                "mode_superseded": "a label change another took the place of (audit trail)",
                "undo": "the operator's undo key; mode: the mode gone back to",
                "marker": "an operator marker; message: its note",
                "device_event": "a device or pipeline event: gaps, losses, reconnects, stalls",
                "heel_contact": "a heel contact of the instrumented leg; source: imu "
                "(detected from the thigh IMU) or simulator (the simulated walk's truth); "
                "mode: the terrain under the foot, where known",
                "toe_off": "a toe off of the instrumented leg (source and mode as for "
                "heel_contact)",
            },
        },
        "mode": {"Description": "the locomotion mode keyed", "Levels": modes},
        "source": {
            "Description": "operator (a key press), start (the mode in force when the trial "
            "started), simulator, undo:<MODE>, correction (labelled offline); for gait "
            "events imu or simulator"
        },
        "in_reference": {
            "Description": "the change defines the locomotion reference (undos applied)",
            "Levels": {"true": "yes", "false": "no"},
        },
        "undone": {
            "Description": "a later undo took this change back",
            "Levels": {"true": "yes", "false": "no"},
        },
        "device": {"Description": "camera, imu, operator, pipeline, recorder, ..."},
        "kind": {
            "Description": "the event's kind: label, marker, gap, lost, reconnected, stall, ..."
        },
        "message": {"Description": "the event in words; a marker's note"},
    }


# ---- walkcap's per-frame results (the derivative) ----------------------------------------

FRAME_COLUMNS = (
    ("frame_index", "the camera's frame index", None),
    ("label", "the operator's mode in force at the frame (undos applied)", None),
    ("terrain", "the terrain reference: what the image shows", None),
    ("locomotion", "the locomotion reference: the mode keyed live", None),
    *((f"p_{m}", f"the CNN's softmax for {m}", None) for m in MODES),
    ("cnn_decision", "the CNN's own decision (largest p_)", None),
    *((f"posterior_{m}", f"the fused posterior for {m}", None) for m in MODES),
    ("decision", "the fused decision for this frame", None),
    ("decision_at_frame", "the frame whose arrival produced the decision", None),
    ("voted", "the fused decision after voting", None),
    ("terrain_kind", "what the profile fits: stairs, ramp, level, unknown", None),
    ("terrain_slope_deg", "slope, positive uphill, net of the IMU's tilt error", "deg"),
    ("terrain_tilt_offset_deg", "the IMU's tilt error learned on level ground", "deg"),
    ("terrain_ahead_slope_deg", "slope of the ground 1.0 m ahead, positive uphill", "deg"),
    ("terrain_riser_m", "stairs: step height", "m"),
    ("terrain_tread_m", "stairs: step depth", "m"),
    ("terrain_direction", "up or down", None),
    ("terrain_steps", "risers seen", None),
    ("preprocess_flag", "why the classifier image is empty; n/a when it is not", None),
)


def frames_rows(frames, first_ns: int | None) -> tuple[list[str], list[str]]:
    """The derivative's frames.tsv: header and rows, onset on the motion file's time."""
    t0 = first_ns if first_ns is not None else 0
    names = [c for c, _, _ in FRAME_COLUMNS if c in frames.columns]
    header = ["onset", "duration", *names]
    values = [frames[c].tolist() for c in names]
    rows = []
    for k, t in enumerate(frames["time_ns"]):
        cells = [seconds(int(t) - t0), NA]
        for col in values:
            v = _value(col[k])
            cells.append(text(v) if isinstance(v, str) else _number(v))
        rows.append("\t".join(cells))
    return header, rows


def frames_json(meta: Metadata) -> dict:
    software = meta.software
    out = {
        "Description": "walkcap's results per camera frame: the terrain CNN's probabilities, "
        "the fused decision, the terrain features",
        "onset": {
            "Description": "the frame's time, seconds from the first IMU sample of the "
            "raw motion file",
            "Units": "s",
        },
        "duration": {"Description": "n/a: a frame is an instant", "Units": "s"},
    }
    for name, description, units in FRAME_COLUMNS:
        out[name] = {"Description": description, **({"Units": units} if units else {})}
    out["walkcap"] = {
        "model_hash": software.model_hash if software.has("model_hash") else "",
        "walkcap_version": software.walkcap_version if software.has("walkcap_version") else "",
        "fusion_method": software.fusion_method if software.has("fusion_method") else "",
        "recording_id": meta.recording.id if meta.recording.has("id") else "",
    }
    return out
