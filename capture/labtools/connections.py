"""The session's optional connections to the lab's tools: LSL outlets and inlets,
LabRecorder-style remote control, a live Foxglove server.

Each is started from the configuration ([lsl], [foxglove]) once the session runs, and each
is optional: one that cannot start (no pylsl, a port in use) is one line in `problems` and
an event, and the session runs on without it.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from pathlib import Path

from capture.errors import CaptureError
from devices.base import DeviceEvent
from devices.clock import now_ns

log = logging.getLogger(__name__)


class SessionController:
    """What remote control's start and stop do in a headless session."""

    def __init__(self, session, info, pattern: str | None = None) -> None:
        self.session = session
        self.info = info  # the SubjectInfo the next trial starts from
        self.pattern = pattern  # [session] subject_pattern

    def remote_start(self, request) -> str:
        if self.session.recording:
            return "already recording"
        info = trial_info(self.info, request, self.pattern)
        # the remote trial's folder is its own: the configured one stays the operator's
        path = self.session.start_recording(dataclasses.replace(info), folder=request.root or None)
        self.info = info
        return f"recording {path}"

    def remote_stop(self) -> str:
        if not self.session.recording:
            return "not recording"
        stats = self.session.stop_recording()
        self.info = dataclasses.replace(self.info, trial=self.info.trial + 1)
        return f"saved {stats.path}" if stats is not None else "stopped"


def remote_folder(recordings: str | Path, root: str, any_root: bool = False) -> Path:
    """The folder a remote `{root:DIR}` names: relative roots are taken in the recordings
    folder, and one outside it is refused unless `any_root` ([lsl] remote_any_root)."""
    if not root.isprintable():
        raise CaptureError("root: a folder name without control characters")
    base = Path(recordings).resolve()
    folder = (base / root).resolve()  # an absolute root stands alone; `..` and links resolved
    if not any_root and not folder.is_relative_to(base):
        raise CaptureError(
            f"root {root!r} is outside the recordings folder {base} "
            f"(a folder in it, or [lsl] remote_any_root = true)"
        )
    return folder


def checked_request(config, request):
    """A remote `filename`'s TrialRequest as a trial takes it (root resolved and confined,
    subject, condition and trial as the form checks them), or CaptureError."""
    from capture.live.trials import SubjectInfo

    if request.root:
        request.root = str(
            remote_folder(config.session.recordings, request.root, config.lsl.remote_any_root)
        )
    trial_info(SubjectInfo(), request, config.session.subject_pattern)
    return request


def trial_info(info, request, pattern: str | None = None):
    """The SubjectInfo a remote `filename` asked for, on top of the current one; a subject
    it names fits `pattern` ([session] subject_pattern)."""
    changes = {}
    if request.subject:
        changes["subject"] = request.subject
    if request.condition:
        changes["condition"] = request.condition
    if request.trial is not None:
        changes["trial"] = request.trial
    if request.notes:
        extra = " ".join(f"{k}={v}" for k, v in sorted(request.notes.items()))
        changes["notes"] = f"{info.notes} {extra}".strip()
    new = dataclasses.replace(info, **changes)
    new.validate(pattern if request.subject else None)
    return new


class LabTools:
    """Start what the configuration asks for beside a running session; stop it all."""

    def __init__(self, session, config, controller=None) -> None:
        self.session = session
        self.config = config
        self.controller = controller
        self.outlets = None
        self.inlets = None
        self.remote = None
        self.foxglove = None
        self.problems: list[str] = []

    def start(self) -> LabTools:
        lsl, fox = self.config.lsl, self.config.foxglove
        if lsl.enabled:
            self._try("LSL outlets", self._start_outlets)
        if lsl.record:
            self._try("LSL inlets", self._start_inlets)
        if lsl.remote_control and self.controller is not None:
            self._try("remote control", self._start_remote)
        if fox.enabled:
            self._try("Foxglove live view", self._start_foxglove)
        return self

    def _try(self, what: str, start) -> None:
        try:
            start()
        except CaptureError as e:
            self._problem(str(e))
        except Exception as e:  # an optional tool never takes the session down
            log.exception("%s", what)
            self._problem(f"{what} not started: {type(e).__name__}: {e}")

    def _problem(self, message: str) -> None:
        self.problems.append(message)
        self.session.add_event(DeviceEvent(now_ns(), "lab", "unavailable", message))

    def _start_outlets(self) -> None:
        from capture.labtools.lsl import LslOutlets

        cfg = self.config
        snap = self.session.snapshot()
        imu_id = (snap.imu.details or {}).get("device_id", "") if snap.imu else ""
        cam_id = (snap.camera.details or {}).get("camera_id", "") if snap.camera else ""
        self.outlets = LslOutlets(
            imu_rate_hz=cfg.imu.rate_hz,
            camera_fps=cfg.camera.fps,
            imu_id=str(imu_id or cfg.imu.port or cfg.imu.backend),
            camera_id=str(cam_id or cfg.camera.camera_id or cfg.camera.backend),
        )
        self.session.add_tap(self.outlets)

    def _start_inlets(self) -> None:
        from capture.labtools.lsl import LslInlets

        self.inlets = LslInlets(
            self.config.lsl.record, self.session.active_recorder, self.session.add_event
        )
        self.inlets.start()

    def _start_remote(self) -> None:
        from capture.labtools.remote import RemoteControl

        lsl = self.config.lsl
        self.remote = RemoteControl(
            self.controller,
            lsl.remote_port,
            on_event=self.session.add_event,
            check=functools.partial(checked_request, self.config),
            token=lsl.remote_token,
        ).start()

    def _start_foxglove(self) -> None:
        from capture.labtools.foxglove_live import FoxgloveLive

        fox = self.config.foxglove
        self.foxglove = FoxgloveLive(fox.host, fox.port, fox.image_hz)
        self.session.add_tap(self.foxglove)

    def describe(self) -> list[str]:
        """One line per running tool, for the terminal."""
        lines = []
        if self.outlets is not None:
            lines.append("LSL outlets: walkcap IMU, walkcap Terrain, walkcap Markers")
        if self.inlets is not None:
            lines.append(f"LSL inlets: recording {', '.join(self.inlets.names)}")
        if self.remote is not None:
            lines.append(f"remote control: 127.0.0.1:{self.remote.port} (LabRecorder commands)")
        if self.foxglove is not None:
            lines.append(f"Foxglove: {self.foxglove.url} (layout {Path(self.foxglove_layout())})")
        return lines

    @staticmethod
    def foxglove_layout() -> Path:
        from capture.labtools.foxglove_live import LAYOUT

        return LAYOUT

    def stop(self) -> None:
        for tap in (self.outlets, self.foxglove):
            if tap is not None:
                self.session.remove_tap(tap)
                tap.close()
        for part in (self.remote, self.inlets):
            if part is not None:
                try:
                    (part.close if hasattr(part, "close") else part.stop)()
                except Exception as e:
                    log.warning("stopping %s: %s", type(part).__name__, e)
        self.outlets = self.foxglove = self.remote = self.inlets = None
