"""The Textual application: opens the session, shows the form and the live screen.

The session (devices, pipeline, recorder) runs on its own threads. Everything that may
take time (opening devices, loading the model, starting or finalising a recording,
stopping) runs in a thread worker that reports back with a message (tui/messages.py),
so the UI never waits and a key is handled, and a label stamped, at once.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from textual import work
from textual.actions import SkipAction
from textual.app import App
from textual.binding import Binding
from textual.css.query import NoMatches
from textual.reactive import reactive
from textual.screen import ModalScreen

from capture.config import Config
from capture.live.preflight import CheckItem, PreflightReport
from capture.live.trials import SubjectInfo
from capture.recording.writer import RecorderState, RecorderStats
from devices.frames import MODES
from tui import messages
from tui.live_screen import LiveScreen
from tui.session_screen import SessionScreen, load_remembered, save_last_session
from tui.source import Playback, Source
from tui.widgets.notices import Notice
from tui.widgets.quit_dialog import QuitDialog
from tui.widgets.recording_panel import clock_text, human_bytes

log = logging.getLogger(__name__)


def default_session_factory(config: Config) -> Source:
    from capture.live.session import Session

    return Session(config)


def describe_error(e: BaseException) -> str:
    """One line for the operator; our own errors carry a message meant to be read as is."""
    from devices.errors import WalkcapError

    if isinstance(e, WalkcapError):
        return str(e)
    if isinstance(e, OSError) and e.strerror:
        return f"{e.strerror}{': ' + str(e.filename) if e.filename else ''}"
    return f"{type(e).__name__}: {e}"


def default_preflight(session) -> PreflightReport:
    from capture.live import preflight

    return preflight.run(session)


@dataclass
class TrialRecord:
    """A trial recorded in this session, for the trials panel and the list printed on quit."""

    trial: int
    path: str
    duration_s: float = 0.0
    size_bytes: int = 0
    labels: int = 0
    gaps: dict = field(default_factory=dict)
    failed: str = ""  # why the recording failed (what reached the disk is readable)
    late: dict = field(default_factory=dict)  # late deliveries: the host stalled, nothing lost

    def line(self) -> str:
        gaps = f"gaps camera {self.gaps.get('camera', 0)}, IMU {self.gaps.get('imu', 0)}"
        if any(self.late.values()):
            gaps += ", late " + ", ".join(
                f"{'IMU' if s == 'imu' else s} {n}" for s, n in self.late.items() if n
            )
        state = f"  FAILED: {self.failed}" if self.failed else ""
        size = human_bytes(self.size_bytes)
        return (
            f"trial {self.trial:<3} {clock_text(self.duration_s)}  {size:>8}  "
            f"{self.labels} label{'s' if self.labels != 1 else ''}  {gaps}  {self.path}{state}"
        )


def keymap(config: Config) -> dict[str, str]:
    """config.keys -> Textual keymap over the live screen's binding ids."""
    return {
        f"walkcap.{name}": value for name, value in dataclasses.asdict(config.keys).items() if value
    }


class WalkcapApp(App):
    TITLE = "walkcap"
    CSS_PATH = "walkcap.tcss"
    # size classes; walkcap.tcss says what each keeps and what gives way
    HORIZONTAL_BREAKPOINTS = [(0, "-slim"), (100, "-narrow"), (120, "-normal"), (150, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (28, "-medium"), (40, "-tall")]
    ENABLE_COMMAND_PALETTE = False
    # a key no form field takes, shown in every footer; the mode keys label with a dialog
    # open over the live screen (help, marker note, quit question) as they do without one
    BINDINGS = [
        Binding("ctrl+q", "quit", "Quit", priority=True),
        *[
            Binding(
                str(i + 1),
                f"label_through_dialog('{m}')",
                m,
                id=f"walkcap.mode_{m.lower()}",
                priority=True,
                show=False,
            )
            for i, m in enumerate(MODES)
        ],
    ]

    status: reactive[str] = reactive("")  # starting devices… / stopping… / an error

    def __init__(
        self,
        config: Config | None = None,
        session: Source | None = None,
        session_factory: Callable[[Config], Source] | None = None,
        *,
        subject: SubjectInfo | None = None,
        ask_subject: bool = True,
        start_status: str = "starting devices…",
        drills: bool = False,
        preflight: Callable[[Source], PreflightReport] | None = None,
    ) -> None:
        """`session`: a ready-made source (tests pass a fake); otherwise `session_factory`
        (default: capture.live.session.Session) builds one from the configuration in a worker.
        `preflight(session) -> PreflightReport` runs before the first trial (default: the
        full check for a session built here; none for a ready-made source). `drills`: keys
        that inject faults into mock devices."""
        super().__init__()
        self.config = config or Config()
        self.session = session
        self.session_factory = session_factory or default_session_factory
        if subject is None:
            subject = self._remembered_subject()
        self.subject = subject
        self.ask_subject = ask_subject
        self.start_status = start_status
        self.ready = False  # the session started: snapshots and commands go to it
        self.status_is_error = False
        self.recording_path: Path | None = None
        self._busy_recording = False
        self._quitting = False
        self._start_failed = False
        self.start_error: str | None = None  # why the devices did not start, for the CLI
        self._subject_confirmed = not ask_subject
        self._builds_session = session is None
        self.drills = drills
        self._preflight = preflight or (default_preflight if session is None else None)
        self.preflight_state = "none"  # none | running | ok | failed
        self.preflight_report: PreflightReport | None = None
        self.trials: list[TrialRecord] = []
        self.lab = None  # LSL, remote control, Foxglove: capture.labtools.connections.LabTools
        self.notices: list[Notice] = []  # this session's notices, oldest first

    def _remembered_subject(self) -> SubjectInfo:
        """The form confirmed last, its next free trial in the recordings folder; the
        remembered operator unless one is configured."""
        remembered = load_remembered(days=self.config.session.remember_days)
        if not self.config.session.operator:
            self.config.session.operator = remembered.operator
        last = remembered.last
        return remembered.form_for(last.subject, last.condition, self.config.session.recordings)

    @property
    def source(self) -> Source | None:
        """What the live screen reads and commands: the session, once it runs."""
        return self.session if self.ready else None

    def on_mount(self) -> None:
        self.set_keymap(keymap(self.config))
        self.push_screen(LiveScreen())
        if self.ask_subject:
            self.push_screen(SessionScreen(self.subject), self._on_subject)
        self._set_status(self.start_status)
        self.start_session()

    def notify(
        self,
        message: str,
        *,
        title: str = "",
        severity="information",
        timeout: float | None = None,
        markup: bool = True,
        logged: str | None = None,
    ) -> None:
        """A notice goes to the live screen's notice line, never over its panels (a toast
        would hide the newest seconds of the strips); only the session form, which has no
        notice line, shows it as a toast as well. Thread-safe, as App.notify is. `logged`:
        what tui.log gets instead of the text (the operator's own words stay out of it)."""
        text = f"{title}: {message}" if title else str(message)
        notice = Notice(" ".join(text.split()), str(severity))
        level = {"error": logging.ERROR, "warning": logging.WARNING}.get(severity, logging.INFO)
        # tui.log: what the operator was told
        log.log(level, "notice: %s", notice.text if logged is None else logged)
        self.post_message(messages.NoticePosted(notice, title, message, severity, timeout, markup))

    def on_notice_posted(self, event: messages.NoticePosted) -> None:
        self.notices.append(event.notice)
        del self.notices[:-200]
        live = [s for s in self.screen_stack if isinstance(s, LiveScreen)]
        for screen in live:
            try:
                screen.show_notice(event.notice)
            except NoMatches:  # the app is closing: its widgets are gone
                pass
        if not live or isinstance(self.screen, SessionScreen):
            super().notify(
                event.message,
                title=event.title,
                severity=event.severity,
                timeout=event.timeout,
                markup=event.markup,
            )

    def _set_status(self, text: str, error: bool = False) -> None:
        self.status_is_error = error
        self.status = text

    # ---- session life cycle -----------------------------------------------------------

    @work(thread=True, exclusive=True, group="session")
    def start_session(self) -> None:
        try:
            if self.session is None:
                self.session = self.session_factory(self.config)
            self.session.start()
        except Exception as e:  # shown to the operator; the UI stays up to read it
            log.exception("starting the session")
            self.post_message(messages.SessionFailed(describe_error(e)))
            return
        self._start_lab_tools()
        self.post_message(messages.SessionStarted())

    def _start_lab_tools(self) -> None:
        """What [lsl] and [foxglove] ask for; one that cannot start is a notice, no more."""
        lsl, fox = self.config.lsl, self.config.foxglove
        if not (lsl.enabled or lsl.record or lsl.remote_control or fox.enabled):
            return
        from capture.labtools.connections import LabTools

        self.lab = LabTools(self.session, self.config, _RemoteForApp(self)).start()
        for line in self.lab.describe():
            log.info("%s", line)
            self.call_from_thread(self.notify, line, timeout=6)
        for problem in self.lab.problems:
            self.call_from_thread(self.notify, problem, severity="warning", timeout=10)

    def remote_start(self, request) -> None:
        """The remote control's start: the trial it named, as if the operator pressed r."""
        from capture.errors import CaptureError
        from capture.labtools.connections import trial_info

        source = self.source
        if source is None or source.recording or self._busy_recording:
            return
        try:
            self.subject = trial_info(self.subject, request, self.config.session.subject_pattern)
        except CaptureError as e:
            self.notify(f"remote start refused: {e}", severity="error", timeout=10)
            return
        self._subject_confirmed = True
        self._busy_recording = True
        # the remote trial's folder is its own: the configured one stays the operator's
        self._start_recording(dataclasses.replace(self.subject), request.root or None)

    def remote_stop(self) -> None:
        source = self.source
        if source is not None and source.recording and not self._busy_recording:
            self._busy_recording = True
            self._set_status("finalising the recording…")
            self._stop_recording()

    def on_session_started(self, _: messages.SessionStarted) -> None:
        self.ready = True
        replay = self.session
        if isinstance(replay, Playback) and replay.subject_info is not None:
            self.subject = replay.subject_info  # a replay shows its recording's form
        self._set_status("")
        if self._quitting:  # quit was asked while the devices were opening
            self.stop_session()
        elif self._preflight is not None and self.preflight_state != "ok":
            self.start_preflight()

    # ---- pre-flight -------------------------------------------------------------------

    def start_preflight(self) -> None:
        self.preflight_state = "running"
        self._set_status("pre-flight check: devices, model, output folder, disk…")
        self._refresh_live()
        self._preflight_worker()

    @work(thread=True, exclusive=True, group="preflight")
    def _preflight_worker(self) -> None:
        try:
            report = self._preflight(self.session)
        except Exception as e:
            log.exception("pre-flight")
            report = PreflightReport([CheckItem("check", False, "", describe_error(e))])
        self.post_message(messages.PreflightDone(report))

    def on_preflight_done(self, message: messages.PreflightDone) -> None:
        report = message.report
        self.preflight_report = report
        self.preflight_state = "ok" if report.ok else "failed"
        if report.ok:
            self._set_status("")
        else:
            self._set_status(
                f"pre-flight failed: {report.reason()} (c checks again; ctrl+r in the form)",
                error=True,
            )
            self.notify(
                f"{report.reason()} — c checks again",
                title="pre-flight failed: recording blocked",
                severity="error",
                timeout=15,
            )
        self._refresh_live()

    @property
    def preflight_reason(self) -> str:
        report = self.preflight_report
        return report.reason() if report is not None else ""

    def retry(self) -> None:
        """c (ctrl+r in the form): start the devices again after a failure, or re-run the
        pre-flight check; in place, with the form's values kept."""
        if self._start_failed:
            self._start_failed = False
            self.start_error = None
            if self._builds_session:
                self.session = None
            self._set_status("starting devices again…")
            self.start_session()
        elif self.ready and self._preflight is not None and self.preflight_state != "running":
            if self.session is not None and self.session.recording:
                return
            self.start_preflight()

    def inject(self, device: str, fault: str, **kw) -> None:
        """--drills: a fault of a mock device (the IMU unplugged, the camera stalled)."""
        if not self.drills or not self.ready:
            return
        try:
            self.session.inject(device, fault, **kw)
        except Exception as e:
            self.notify(describe_error(e), severity="error")
            return
        self.notify(f"drill: {device} {fault}", severity="warning", timeout=3)

    def on_session_failed(self, message: messages.SessionFailed) -> None:
        self._start_failed = True
        self.start_error = message.error
        self._set_status(
            f"could not start: {message.error} (c retries; ctrl+r in the form; ctrl+q quits)",
            error=True,
        )
        self.notify(message.error, title="could not start", severity="error", timeout=30)
        if self._quitting:
            self.exit(return_code=1)

    def request_quit(self) -> None:
        """q: ask first while a trial records; a clean stop finalises its file."""
        if self._quitting:
            return  # already stopping
        if self.session is not None and self.ready and self.session.recording:
            self.push_screen(QuitDialog(), lambda yes: self.stop_session() if yes else None)
        elif self.ready and isinstance(self.session, Playback) and self.session.unsaved:
            self.push_screen(
                QuitDialog(
                    "The label corrections are not saved (w saves them). Quit anyway?",
                    yes="Quit without saving (y)",
                    no="Stay (n)",
                ),
                lambda yes: self.stop_session() if yes else None,
            )
        else:
            self.stop_session()

    def stop_session(self) -> None:
        self._quitting = True
        if self.ready:
            self._set_status("stopping…")
            self._stop_worker()
        elif self._start_failed:
            self.exit(return_code=1)
        else:  # still opening the devices: on_session_started stops them, then we exit
            self._set_status("quitting as soon as the devices have started…")

    def check_action(self, action: str, parameters: tuple) -> bool | None:
        if action == "label_through_dialog":  # only a dialog over the live screen
            return isinstance(self.screen, ModalScreen) and any(
                isinstance(s, LiveScreen) for s in self.screen_stack
            )
        return True

    def action_label_through_dialog(self, mode: str) -> None:
        """A mode key with a dialog over the live screen labels as on the live screen;
        anywhere else (the live screen itself, the form) the key goes its usual way."""
        live = [s for s in self.screen_stack if isinstance(s, LiveScreen)]
        if not live or not isinstance(self.screen, ModalScreen):
            raise SkipAction()
        live[-1].action_label(mode)

    async def action_quit(self) -> None:
        """ctrl+q too goes through the clean stop (and the question while recording)."""
        self.request_quit()

    @work(thread=True, exclusive=True, group="session")
    def _stop_worker(self) -> None:
        if self.lab is not None:
            self.lab.stop()
            self.lab = None
        try:
            stats = self.session.stop()
        except Exception as e:
            log.exception("stopping the session")
            self.call_from_thread(self.notify, describe_error(e), severity="error")
            stats = None
        if stats is not None and self.preflight_state != "running":  # not the check's probe
            self.post_message(messages.RecordingStopped(stats, self.recording_path))
        self.post_message(messages.SessionStopped())

    def on_session_stopped(self, _: messages.SessionStopped) -> None:
        self.ready = False
        self.exit(0)

    # ---- the session form -------------------------------------------------------------

    def _on_subject(self, info: SubjectInfo | None) -> None:
        if info is not None:
            self.subject = info
            self._subject_confirmed = True
            self._refresh_live()

    def open_session_form(self, then_record: bool = False) -> None:
        if self.session is not None and self.ready and self.session.recording:
            self.notify(
                "stop the recording first (the form describes the next trial)",
                severity="warning",
                timeout=3,
            )
            return

        def done(info: SubjectInfo | None) -> None:
            self._on_subject(info)
            if info is not None and then_record:
                self.toggle_recording()

        self.push_screen(SessionScreen(self.subject, can_cancel=True), done)

    # ---- recording --------------------------------------------------------------------

    def toggle_recording(self) -> None:
        source = self.source
        if source is None:
            if self.start_error:
                self.notify(
                    f"the devices did not start: {self.start_error} — c retries",
                    severity="error",
                    timeout=6,
                )
            else:
                self.notify("the devices are still starting", severity="warning", timeout=3)
            return
        if self._busy_recording:
            return  # a start or stop is under way: one press, one action
        if not self._subject_confirmed:
            self.open_session_form(then_record=True)
            return
        if source.recording and self.preflight_state != "running":
            self._busy_recording = True
            self._set_status("finalising the recording…")
            self._stop_recording()
            return
        if self.preflight_state == "running":
            self.notify("the pre-flight check is running (a few seconds)", timeout=3)
            return
        if self.preflight_state == "failed":
            self.notify(
                f"{self.preflight_reason} — c checks again",
                title="pre-flight failed: recording blocked",
                severity="error",
                timeout=8,
            )
            return
        self._busy_recording = True
        self._start_recording(dataclasses.replace(self.subject))

    @work(thread=True, group="recording")
    def _start_recording(self, info: SubjectInfo, folder: str | None = None) -> None:
        try:
            if folder is None:
                path = self.session.start_recording(info)
            else:
                path = self.session.start_recording(info, folder=folder)
        except Exception as e:
            log.exception("starting a recording")
            self.post_message(messages.RecordingFailed(describe_error(e)))
            return
        self.post_message(messages.RecordingStarted(Path(path)))

    @work(thread=True, group="recording")
    def _stop_recording(self) -> None:
        try:
            stats = self.session.stop_recording()
        except Exception as e:
            log.exception("stopping a recording")
            self.post_message(messages.RecordingFailed(describe_error(e)))
            return
        self.post_message(messages.RecordingStopped(stats, self.recording_path))

    def on_recording_started(self, message: messages.RecordingStarted) -> None:
        self._busy_recording = False
        self.recording_path = message.path
        self.bell()  # the operator watches the subject: a sound as well as the banner
        self.notify(f"recording {message.path.name}", timeout=4)
        notice = self.session.trial_notice  # the trial existed: the next one was recorded
        recorded = self.session.trial
        if notice and recorded is not None:
            self.subject = dataclasses.replace(self.subject, trial=recorded.trial)
            self.notify(notice, severity="warning", timeout=10)
        self._refresh_live()

    def on_recording_stopped(self, message: messages.RecordingStopped) -> None:
        self._busy_recording = False
        self._set_status("")
        self.bell()
        self._add_trial(message.stats, message.path)
        self.recording_path = None
        # the next trial of the same subject: advance and remember, even if the app dies now
        self.subject = dataclasses.replace(self.subject, trial=self.subject.trial + 1)
        save_last_session(
            self.subject,
            operator=self.config.session.operator,
            days=self.config.session.remember_days,
        )
        stats = message.stats
        name = Path((stats.path if stats else "") or message.path or "recording").name
        if stats is not None and stats.state == RecorderState.FAILED:
            self.notify(
                f"{name}: {stats.message} (what reached the disk is readable)",
                title="recording failed",
                severity="error",
                timeout=30,
            )
        else:
            size = stats.bytes_written if stats else None
            dropped = stats.dropped if stats else 0
            self.notify(
                f"saved {name}"
                + (f" ({human_bytes(size)})" if size else "")
                + (f", {dropped} messages dropped" if dropped else ""),
                severity="warning" if dropped else "information",
                timeout=6,
            )
        self._refresh_live()

    def _add_trial(self, stats: RecorderStats | None, path: Path | None) -> None:
        if stats is None:
            return
        alarms = self.session.alarms
        failed = stats.state == RecorderState.FAILED
        self.trials.append(
            TrialRecord(
                trial=self.subject.trial,
                path=str(Path(stats.path or path or "").resolve()),
                duration_s=float(stats.duration_s or 0.0),
                size_bytes=int(stats.bytes_written or 0),
                labels=int(stats.labels or 0),
                gaps=dict(alarms.trial_gaps) if alarms is not None else {},
                late=dict(alarms.trial_late) if alarms is not None else {},
                failed=str(stats.message) if failed else "",
            )
        )

    def trials_summary(self) -> list[str]:
        """What this session saved, for the terminal after quit."""
        # a trial still open when the app ended (quit or a fault) is closed by the session
        open_trial = (
            [f"  trial {self.subject.trial}: {self.recording_path} (open when walkcap ended)"]
            if self.recording_path is not None
            else []
        )
        if not self.trials and not open_trial:
            return ["walkcap: no trial recorded in this session"]
        n = len(self.trials) + len(open_trial)
        return (
            [f"walkcap: {n} trial{'s' if n != 1 else ''} saved in this session"]
            + ["  " + t.line() for t in self.trials]
            + open_trial
        )

    def on_recording_failed(self, message: messages.RecordingFailed) -> None:
        self._busy_recording = False
        self._set_status("")
        self.notify(message.error, title="recording", severity="error", timeout=15)
        self._refresh_live()

    # ---- replay: corrections into a new file ------------------------------------------

    def save_corrections(self) -> None:
        if not isinstance(self.source, Playback) or self._busy_recording:
            return
        self._busy_recording = True
        self._set_status("writing the corrected file…")
        self._save_corrections()

    @work(thread=True, group="recording")
    def _save_corrections(self) -> None:
        try:
            path = self.session.save_corrections()  # a Playback: save_corrections() checked
        except Exception as e:
            log.exception("saving corrections")
            self.post_message(messages.RecordingFailed(describe_error(e)))
            return
        self.post_message(messages.CorrectionsSaved(Path(path)))

    def on_corrections_saved(self, message: messages.CorrectionsSaved) -> None:
        self._busy_recording = False
        self._set_status("")
        self.notify(
            f"saved {message.path.name}: its labels are the terrain reference, the live keys "
            "its locomotion reference (the original is unchanged)",
            timeout=8,
        )

    def _refresh_live(self) -> None:
        for screen in self.screen_stack:
            if isinstance(screen, LiveScreen) and not screen.frozen:
                try:
                    screen.refresh_view()
                except NoMatches:  # the app is closing: its widgets are gone
                    pass


class _RemoteForApp:
    """Remote control in the UI: commands go to the app's thread, which shows them."""

    def __init__(self, app: WalkcapApp) -> None:
        self.app = app

    def remote_start(self, request) -> str:
        self.app.call_from_thread(self.app.remote_start, request)
        return "start passed to the UI"

    def remote_stop(self) -> str:
        self.app.call_from_thread(self.app.remote_stop)
        return "stop passed to the UI"
