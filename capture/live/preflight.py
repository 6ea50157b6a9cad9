"""Pre-flight check before the first trial: devices, model, output folder, disk.

Each item says in words what was found and, when it fails, why; a failed item blocks
recording until a retry passes. `walkcap check` prints the same report headless.

The write rate comes from a short probe trial (real data, written and deleted in a
hidden folder inside the output folder): the disk's minutes are minutes of this data.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from capture.live.alarms import DISK_MINUTES_LOW, disk_minutes
from devices.base import DeviceState
from devices.imu.clock import drift_text

MIN_RATE = 0.8  # a device below this fraction of its configured rate fails
SYNC_P99_MS = 5.0  # IMU-to-frame sync error above this (p99): a warning
DRIFT_PPM = 1000.0  # IMU clock drift above this: a warning
PROBE_S = 2.0
SETTLE_S = 0.5


@dataclass
class CheckItem:
    name: str  # camera | imu | model | output folder | disk
    ok: bool
    summary: str  # what was found, in words with units
    reason: str = ""  # why it failed (empty when ok)
    warning: str = ""  # worth knowing, does not block
    details: dict = field(default_factory=dict)


@dataclass
class PreflightReport:
    items: list[CheckItem]
    write_rate_bytes_per_s: float | None = None

    @property
    def ok(self) -> bool:
        return all(item.ok for item in self.items)

    @property
    def failures(self) -> list[CheckItem]:
        return [item for item in self.items if not item.ok]

    def reason(self) -> str:
        """The first failure in one line ("" when everything passed)."""
        bad = self.failures
        return f"{bad[0].name}: {bad[0].reason}" if bad else ""

    def to_dict(self) -> dict:
        return {
            "ok": self.ok,
            "write_rate_bytes_per_s": self.write_rate_bytes_per_s,
            "items": [dataclasses.asdict(i) for i in self.items],
        }

    def lines(self) -> list[str]:
        out = []
        for item in self.items:
            mark = "ok  " if item.ok else "FAIL"
            out.append(f"{mark} {item.name:<13} {item.summary}")
            if item.reason:
                out.append(f"     {'':<13} {item.reason}")
            if item.warning:
                out.append(f"     {'':<13} warning: {item.warning}")
        return out


def device_item(name: str, status, sync: dict | None = None) -> CheckItem:
    """A device as its status shows it after the settle time."""
    if status is None:
        return CheckItem(name, False, "not found", "the device did not open")
    d = status.details or {}
    ident = d.get("device_id") or d.get("id") or d.get("camera") or d.get("course") or "?"
    if status.backend == "mock":
        ident = f"mock {ident}"
    details = {
        "backend": status.backend,
        "id": str(ident),
        "firmware": str(d.get("firmware", "")),
        "configured_rate_hz": status.configured_rate_hz,
        "measured_rate_hz": round(status.measured_rate_hz, 2),
        "dropped": status.dropped,
        "errors": status.errors,
    }
    parts = [f"id {ident}"]
    if details["firmware"]:
        parts.append(f"firmware {details['firmware']}")
    unit = "fps" if name == "camera" else "Hz"
    parts.append(f"rate {status.measured_rate_hz:.1f} of {status.configured_rate_hz:g} {unit}")
    parts.append(f"drops {status.dropped}")
    if d.get("frame_path"):  # how the camera's binding hands over frames
        details["frame_path"] = str(d["frame_path"])
        parts.append(f"frames via {d['frame_path']}")
    drift = d.get("drift_ppm", d.get("clock_drift_ppm"))
    warning = ""
    if drift is not None:
        details["clock_drift_ppm"] = round(float(drift), 1)
        uncertainty = d.get("drift_uncertainty_ppm")
        if "drift_uncertainty_ppm" in d:  # how surely: a short probe fits it loosely
            details["clock_drift_uncertainty_ppm"] = (
                None if uncertainty is None else round(float(uncertainty), 1)
            )
            parts.append(f"clock drift {drift_text(float(drift), uncertainty)}")
        else:
            parts.append(f"clock drift {float(drift):+.0f} ppm")
        if abs(float(drift)) > DRIFT_PPM:
            warning = f"clock drift {float(drift):+.0f} ppm is unusually large"
    if sync:
        details["sync_error_p99_ms"] = round(sync.get("p99_ms", 0.0), 3)
        parts.append(f"sync error p99 {sync.get('p99_ms', 0.0):.1f} ms")
        if sync.get("p99_ms", 0.0) > SYNC_P99_MS:
            warning = f"IMU-to-frame sync error p99 {sync['p99_ms']:.1f} ms"
    reason = ""
    if status.state != DeviceState.OK:
        reason = f"{status.state}: {status.message or 'not streaming'}"
    elif status.configured_rate_hz and status.measured_rate_hz < (
        MIN_RATE * status.configured_rate_hz
    ):
        reason = (
            f"measured {status.measured_rate_hz:.1f} Hz, below {MIN_RATE:.0%} of the "
            f"configured {status.configured_rate_hz:g} Hz"
        )
    return CheckItem(name, not reason, ", ".join(parts), reason, warning, details)


def model_item(classifier, path: str) -> CheckItem:
    """The model as loaded, and one probe inference that must give finite probabilities."""
    meta = getattr(classifier, "metadata", None) or {}
    digest = str(meta.get("weights_sha256", ""))
    classes = list(getattr(classifier, "classes", ()) or ())
    where = path or f"bundled ({getattr(classifier, 'path', '')})"
    details = {"path": str(where), "sha256": digest, "classes": classes}
    try:
        probs = np.asarray(classifier.predict(np.zeros((100, 100), np.uint8)), dtype=float)
        finite = bool(np.all(np.isfinite(probs))) and probs.size == len(classes or probs)
    except Exception as e:  # a broken model is a failed item, not a crash
        return CheckItem("model", False, str(where), f"probe inference failed: {e}", "", details)
    details["probe"] = [round(float(p), 4) for p in probs]
    summary = f"{where}, sha256 {digest[:12] or '?'}, classes {' '.join(classes)}"
    if not finite:
        return CheckItem("model", False, summary, "probe inference is not finite", "", details)
    return CheckItem("model", True, summary + ", probe finite", details=details)


def folder_item(folder: Path) -> CheckItem:
    """The output folder exists (or can be made) and takes a file."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".walkcap-check-") as f:
            f.write(b"walkcap")
            f.flush()
    except OSError as e:
        file = next((p for p in (folder, *folder.parents) if p.is_file()), None)
        reason = (
            f"{file} is a file, not a folder: set [session] recordings or --out to a folder"
            if file is not None
            else f"not writable: {e.strerror or e}"
        )
        return CheckItem("output folder", False, str(folder.resolve()), reason)
    checkout = git_work_tree(folder)
    warning = (
        f"inside the git work tree {checkout}: `git clean -xfd` there deletes the recordings "
        "without asking; keep them on a data disk: walkcap config --set "
        "session.recordings=/path/to/data (or --out DIR)"
        if checkout is not None
        else ""
    )
    details = {"git_work_tree": str(checkout)} if checkout is not None else {}
    return CheckItem(
        "output folder", True, f"{folder.resolve()} writable", warning=warning, details=details
    )


def git_work_tree(folder: Path) -> Path | None:
    """The git work tree `folder` lies in (a `.git` folder or worktree file above it), if
    any: a `git clean -xfd` there deletes whatever the folder holds, ignored or not."""
    here = folder.resolve()
    for candidate in (here, *here.parents):
        if (candidate / ".git").exists():
            return candidate
    return None


def _existing(folder: Path) -> Path:
    folder = folder.absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def disk_item(folder: Path, rate: float | None) -> CheckItem:
    try:
        free = shutil.disk_usage(_existing(folder)).free
    except OSError as e:
        return CheckItem("disk", False, "unknown", f"cannot read free space: {e.strerror}")
    minutes = disk_minutes(free, rate)
    details = {"free_bytes": free, "write_rate_bytes_per_s": rate, "minutes": minutes}
    summary = f"{free / 1e9:.1f} GB free"
    if minutes is None:
        return CheckItem("disk", True, summary + " (write rate not measured)", details=details)
    summary += f", {minutes:.0f} min at {rate / 1e6:.2f} MB/s"
    if minutes < DISK_MINUTES_LOW:
        reason = f"holds {minutes:.0f} min, below {DISK_MINUTES_LOW:.0f} min"
        return CheckItem("disk", False, summary, reason, details=details)
    return CheckItem("disk", True, summary, details=details)


def probe_write_rate(session, folder: Path, seconds: float, sleep=time.sleep) -> float | None:
    """Bytes per second of a short probe trial in a hidden folder, deleted afterwards."""
    from capture.live.trials import SubjectInfo
    from capture.recording.writer import RecorderState

    probe_dir = Path(tempfile.mkdtemp(dir=folder, prefix=".walkcap-check-"))
    config = session.config.session
    saved = config.recordings
    try:
        config.recordings = str(probe_dir)
        session.start_recording(SubjectInfo(subject="preflight", condition="check"))
        sleep(seconds)
        stats = session.stop_recording()
    finally:
        config.recordings = saved
        session.alarms.recordings = Path(saved)
        shutil.rmtree(probe_dir, ignore_errors=True)
    if stats is None or stats.duration_s <= 0 or stats.state == RecorderState.FAILED:
        return None
    return stats.bytes_written / stats.duration_s


def run(session, *, probe_s: float = PROBE_S, settle_s: float = SETTLE_S, sleep=time.sleep):
    """Check a started session; returns a PreflightReport (never raises for a failure)."""
    config = session.config
    folder = Path(config.session.recordings)
    sleep(settle_s)
    items: list[CheckItem] = []
    writable = folder_item(folder)
    rate = None
    probe_error = ""
    if writable.ok and probe_s > 0:
        try:
            rate = probe_write_rate(session, folder, probe_s, sleep)
        except Exception as e:  # the check reports it; the session goes on
            probe_error = f"probe recording failed: {e}"
    else:
        sleep(max(probe_s, PROBE_S))  # the devices' rates and clock fit need the time anyway
    snap = session.snapshot()
    items.append(device_item("camera", snap.camera))
    recent = getattr(session, "recent_sync_ms", None)
    items.append(device_item("imu", snap.imu, recent() if recent is not None else snap.sync))
    items.append(model_item(session.pipeline.classifier, config.model.path))
    if probe_error:
        writable = dataclasses.replace(writable, ok=False, reason=probe_error)
    items.append(writable)
    items.append(disk_item(folder, rate))
    return PreflightReport(items, rate)


def start_failure(config, error: BaseException) -> PreflightReport:
    """The report when the session did not start: which part failed, and the folder and
    disk checked anyway (they need no device)."""
    from inference.errors import InferenceError

    text = str(error) or type(error).__name__
    folder = Path(config.session.recordings)
    if isinstance(error, InferenceError):
        items = [CheckItem("model", False, config.model.path or "bundled", text)]
    else:
        items = [CheckItem("devices", False, "did not start", text)]
    items += [folder_item(folder), disk_item(folder, None)]
    return PreflightReport(items)
