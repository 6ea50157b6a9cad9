"""The live screen: devices, the image and profile, decisions, the last 20 s, the recording.

It pulls one snapshot from its source at most REFRESH_HZ times a second (whatever the
frame rate), hands each widget its part, and sends the operator's keys to the source as
commands that only touch memory: nothing here waits on a device or the disk.
"""

from __future__ import annotations

import bisect
import dataclasses
import logging
from pathlib import Path

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import Screen
from textual.widgets import Footer, Static

from capture.live.session import Snapshot
from capture.recording.labels import effective_changes
from capture.recording.writer import RecorderState
from devices import clock
from devices.clock import now_ns
from devices.frames import MODE_NAMES, MODES
from inference.evaluation.metrics import TITLES
from tui.source import Playback
from tui.widgets.binary_image import BinaryImage
from tui.widgets.decision import DecisionDisplay
from tui.widgets.device_panel import DevicePanel, event_sentence
from tui.widgets.features import FeaturesPanel
from tui.widgets.help_screen import HelpScreen, key_label
from tui.widgets.marker_dialog import MarkerDialog
from tui.widgets.modes import mode_text
from tui.widgets.notices import Notice, NoticeLine
from tui.widgets.probability_bars import ProbabilityBars
from tui.widgets.profile_plot import ProfilePlot
from tui.widgets.recording_panel import RecordingPanel, clock_text
from tui.widgets.timeline import TimelineStrips
from tui.widgets.top_bar import TopBar

log = logging.getLogger(__name__)

REFRESH_HZ = 20
# Events that also pop up (all of them show in the device panel); gaps and drops only there.
FAULT_KINDS = {
    "lost": "error",
    "error": "error",
    "device_error": "error",
    "stall": "warning",
    "device_restarted": "warning",
    "end_of_course": "warning",
    "reconnected": "information",
    "resumed": "information",
}
SEEK_S = 5.0


def _binding(key: str, action: str, description: str, field: str, **kw) -> Binding:
    """A binding whose key config.keys.<field> can change (see WalkcapApp.keymap)."""
    return Binding(key, action, description, id=f"walkcap.{field}", **kw)


def pipeline_rows(snap: Snapshot) -> list[tuple[str, str, str]]:
    """Frames processed and the pipeline latency (frame received -> fused decision ready);
    the steps of the trial and the cadence, from the thigh IMU's gait events."""
    rows = [("pipeline", "", "bold"), ("frames", f"{snap.frames}", "")]
    if snap.steps is not None:  # a live session's (a replay shows none)
        cadence = snap.cadence_spm
        pace = f"{cadence:.0f} steps/min" if cadence is not None else "standing"
        rows.append(("steps", f"{snap.steps}, {pace}", ""))
    if snap.latency_ms:
        p50, p99 = snap.latency_ms.get("p50", 0), snap.latency_ms.get("p99", 0)
        rows.append(("latency", f"median {p50:.0f}, p99 {p99:.0f} ms", ""))
    stale = snap.stale_frames
    if stale:  # frames left undecided: no IMU orientation fresh enough to level them
        rows.append(("stale", f"{stale} frames (old IMU)", "#f0a020"))
    return rows


def banner_path(path: Path | None, room: int) -> str:
    """The recording's full path, or as much of its folder as fits before the file name,
    which is always whole: "…/recordings/S03_indoor_t05_20261202-071746.mcap"."""
    if path is None:
        return ""
    full = str(path)
    if len(full) <= room:
        return full
    name = path.name
    keep = room - len(name) - 1  # "…" + the end of the folder
    folder = str(path.parent) + "/"
    return "…" + (folder[-keep:] if keep > 0 else "") + name


class LiveScreen(Screen):
    BINDINGS = [
        *[
            _binding(str(i + 1), f"label('{m}')", m, f"mode_{m.lower()}")
            for i, m in enumerate(MODES)
        ],
        _binding("u", "undo", "undo", "undo"),
        _binding("m", "marker", "marker", "marker"),
        _binding("r", "record", "record", "record"),
        _binding("space", "freeze", "freeze", "freeze"),
        _binding("question_mark", "help", "help", "help"),
        _binding("q", "quit", "quit", "quit"),
        Binding("s", "session_form", "session", show=False),
        Binding("w", "save_corrections", "save labels"),
        Binding("p", "play", "play/pause"),
        Binding("left", "seek(-1)", "-5 s"),
        Binding("right", "seek(1)", "+5 s"),
        Binding("c", "check", "check again"),
        Binding("ctrl+u", "drill('imu', 'disconnect')", "drill: unplug IMU", show=False),
        Binding("ctrl+t", "drill('camera', 'stall')", "drill: stall camera", show=False),
    ]
    # What each action does, for the help screen (keys come from the live bindings).
    HELP = {
        **{f"label('{m}')": f"true mode {m} ({MODE_NAMES[m]}) from now on" for m in MODES},
        "undo": "undo the last label change",
        "marker": "place a marker, with an optional note",
        "record": "start / stop recording a trial (one file per trial)",
        "freeze": "freeze / unfreeze the display (capture and recording go on)",
        "help": "this help",
        "quit": "quit (asks first while recording; the file is finalised)",
        "session_form": "the session form (subject, condition, trial); not while recording",
        "check": "run the pre-flight check again, or start the devices again after a failure",
        "drill('imu', 'disconnect')": "drill (--drills, mock only): unplug the IMU for 2 s",
        "drill('camera', 'stall')": "drill (--drills, mock only): stall the camera for 2 s",
        "save_corrections": "replay: write the labels with your corrections to a new file",
        "play": "replay: play / pause",
        "seek(-1)": "replay: back 5 s",
        "seek(1)": "replay: forward 5 s",
    }

    def __init__(self) -> None:
        super().__init__()
        self.frozen = False
        self.refreshes = 0  # views drawn from a snapshot (tests check freeze with it)
        self._snapshot: Snapshot | None = None
        self._fused: int | None = None
        self._fusion_method = ""  # the one the decision panel's title names
        self._last_event_ns: int | None = None
        self._failure_shown = False
        # The label changes keyed here, undos included (time_ns, mode, source): the true
        # strip shows them as they stand, an undone change as if it never happened.
        self._label_changes: list[tuple[int, str, str]] = []
        self._effective: list[tuple[int, str, str]] = []
        # what the banner, the alarm line and the trials panel show (redrawn when it changes)
        self._banner_shown: tuple[str, str] | None = None
        self._alarms_shown: str | None = None
        self._trials_shown: str | None = None

    def compose(self) -> ComposeResult:
        yield TopBar(id="topbar")
        yield Static("", id="banner")
        yield Static("", id="alarms")
        yield NoticeLine(id="notices")
        with Horizontal(id="main"):
            with Vertical(id="left"):
                yield DevicePanel(id="devices")
                yield RecordingPanel(id="recording")
            yield BinaryImage(id="image")
            pre = self.app.config.preprocess
            yield ProfilePlot(forward_m=(pre.min_forward_m, pre.max_forward_m), id="profile")
            with Vertical(id="right"):
                yield DecisionDisplay(id="decision")
                yield ProbabilityBars(id="probabilities")
                yield FeaturesPanel(id="features")
        yield Static("", id="trials")
        yield TimelineStrips(id="timeline")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        titles = {
            "devices": "devices",
            "recording": "recording",
            "image": "image",
            "profile": "profile",
            "decision": "fused decision",
            "probabilities": "CNN probabilities",
            "features": "terrain geometry",
            "timeline": "last 20 s",
            "trials": "trials this session",
        }
        for wid, title in titles.items():
            self.query_one(f"#{wid}").border_title = title
        self._w = {
            type(w): w for w in self.query("#main *, #timeline, #topbar") if hasattr(w, "present")
        }
        notices = self.app.notices
        if notices:
            self.show_notice(notices[-1])
        self._timer = self.set_interval(1 / REFRESH_HZ, self.refresh_view)
        self.watch(self.app, "status", lambda _: self._show_topbar())
        self.refresh_view()

    # ---- the view ---------------------------------------------------------------------

    def show_notice(self, notice: Notice) -> None:
        """The latest notice, on its own line: it never covers the strips or the decision."""
        self.query_one(NoticeLine).present(notice)

    def refresh_view(self) -> None:
        """Pull one snapshot and show it (the timer calls this; commands too, for feedback)."""
        source = self.app.source
        if source is None:
            self._show_topbar()
            self._show_banner(None)
            error = self.app.start_error
            if error:  # say why, and how to try again, where the devices would be
                rows = [("", f"could not start: {error}", "bold #e04040"), ("", "c retries", "")]
                self._w[DevicePanel].present(None, None, {}, None, rows)
            return
        try:
            snap = source.snapshot()
        except Exception:  # a bug in a snapshot must not take the UI (and the recording) down
            log.exception("snapshot")
            return
        self.present(snap)

    def present(self, snap: Snapshot) -> None:
        if snap.fusion_method != self._fusion_method:  # the session's, or a replay's recorded
            self._fusion_method = snap.fusion_method
            method = TITLES.get(snap.fusion_method, snap.fusion_method)
            self.query_one("#decision").border_title = (
                f"fused: {method}" if method else "fused decision"
            )
        self.refreshes += 1
        self._snapshot = snap
        latest = snap.latest
        key = latest.index if latest is not None else None
        if latest is not None and latest.fused is not None:
            self._fused = latest.fused.decision
        self._w[BinaryImage].present(
            latest.image if latest else None, latest.flag if latest else "", key
        )
        self._w[ProfilePlot].present(latest.profile if latest else None, key)
        self._w[DecisionDisplay].present_switching(snap.switches_last_minute, snap.walker_mode)
        self._w[DecisionDisplay].present(
            self._fused,
            latest.cnn_decision if latest else None,
            snap.label,
            unknown=latest is not None and not latest.decided,
        )
        self._w[ProbabilityBars].present(latest.probabilities if latest else None)
        self._w[FeaturesPanel].present(latest.features if latest else None)
        self._w[TimelineStrips].present(self._labels_as_they_stand(snap.timeline), snap.time_ns)
        faults = [e for e in snap.events if e.device != "operator"]
        self._w[DevicePanel].present(
            snap.camera, snap.imu, snap.sync, faults[-1] if faults else None, pipeline_rows(snap)
        )
        self._show_recording(snap)
        self._notify_new_events(snap)
        self._show_topbar()
        self._show_banner(snap)
        self._show_alarms(snap)
        self._show_trials()

    def _labels_as_they_stand(self, entries: list) -> list:
        """Timeline entries with the operator's labels as they stand now: each frame
        carries the label in force when it was taken, which an undo takes back later."""
        if not self._label_changes or isinstance(self.app.source, Playback):
            return entries
        first = self._label_changes[0][0]
        times = [c[0] for c in self._effective]
        out = []
        for e in entries:
            if e.time_ns >= first:
                k = bisect.bisect_right(times, e.time_ns) - 1
                mode = (self._effective[k][1] if k >= 0 else "") or None
                if mode != e.label:
                    e = dataclasses.replace(e, label=mode)
            out.append(e)
        return out

    def _keyed(self, time_ns: int | None, mode: str, source: str, before: str | None) -> None:
        if time_ns is None:
            return
        if not self._label_changes and before and source != "undo":
            self._label_changes.append((time_ns - 1, before, "operator"))  # the mode in force
        self._label_changes.append((time_ns, mode, source))
        self._effective = effective_changes(self._label_changes)

    def settled(self) -> bool:
        """The paced widgets show the latest snapshot's frame (for tests and screenshots)."""
        snap = self._snapshot
        if snap is None or snap.latest is None:
            return snap is not None
        index = snap.latest.index
        return self._w[BinaryImage].shown_key == index and self._w[ProfilePlot].shown_key == index

    def _elapsed(self, snap: Snapshot | None) -> float | None:
        """Seconds into the trial; None when no trial records (the check's probe is none)."""
        if snap is None or snap.recording_started_ns is None:
            return None
        if self.app.preflight_state == "running":
            return None
        return clock.seconds(snap.time_ns - snap.recording_started_ns)

    def _show_banner(self, snap: Snapshot | None) -> None:
        """The full-width line that says at a glance whether a trial records."""
        app = self.app
        banner = self.query_one("#banner", Static)
        key = key_label(app.config.keys.record)
        elapsed = self._elapsed(snap)
        if isinstance(app.source, Playback):
            text, cls = Text(" ▶ REPLAY — nothing records; 1-5 correct labels, w saves"), "-idle"
        elif elapsed is not None:
            path = app.recording_path
            head = f" ● REC  trial {app.subject.trial}  {clock_text(elapsed)}  "
            cls = "-rec"
            if snap.recording is not None and snap.recording.state == RecorderState.FAILED:
                head = f" ✖ REC FAILED  trial {app.subject.trial}  ({key} closes the file)  "
                cls = "-failed"
            width = banner.size.width or app.size.width
            text = Text(head + banner_path(path.resolve() if path else None, width - len(head)))
        else:
            state = app.preflight_state
            if app.source is None:
                text, cls = Text(" ○ devices not running"), "-idle"
            elif state == "running":
                text, cls = (
                    Text(" ○ pre-flight check running… (recording after it passes)"),
                    "-idle",
                )
            elif state == "failed":
                text = Text(f" ✖ PRE-FLIGHT FAILED: {app.preflight_reason} — c checks again")
                cls = "-failed"
            else:
                ok = "pre-flight ok  " if state == "ok" else ""
                text = Text(f" ○ not recording  {ok}{key}: record trial {app.subject.trial}")
                cls = "-idle"
        if (str(text), cls) != self._banner_shown:
            self._banner_shown = (str(text), cls)
            banner.update(text)
            banner.set_classes(cls)

    def _show_alarms(self, snap: Snapshot) -> None:
        """What needs the operator now, in words and colour (nothing to read when all is well)."""
        state = snap.alarms
        alarms = list(state.alarms) if state is not None else []
        line = Text(no_wrap=True, overflow="ellipsis")
        if not alarms:
            line.append(" no alarms", style="dim")
        for i, alarm in enumerate(alarms):
            if i:
                line.append("  ")
            style = (
                "bold #ffffff on #b02020" if alarm.level == "error" else "bold #000000 on #f0a020"
            )
            line.append(f" {'ALARM' if alarm.level == 'error' else 'WARNING'} {alarm.text} ", style)
        if str(line) != self._alarms_shown:
            self._alarms_shown = str(line)
            self.query_one("#alarms", Static).update(line)

    def _show_trials(self) -> None:
        trials = self.app.trials
        lines = [t.line() for t in trials[-3:]]
        if len(trials) > 3:
            lines.insert(0, f"… {len(trials) - 3} earlier (all are listed on quit)")
        text = "\n".join(lines) if lines else "none yet (each trial's file is listed here)"
        if text != self._trials_shown:
            self._trials_shown = text
            self.query_one("#trials", Static).update(Text(text, style="" if lines else "dim"))

    def _show_recording(self, snap: Snapshot) -> None:
        app = self.app
        elapsed = self._elapsed(snap)
        info = app.subject
        key = key_label(app.config.keys.record)
        source = app.source
        if isinstance(source, Playback):  # a replay records nothing: it saves corrections
            n = len(source.corrections)
            saved = source.saved_path
            hint = (
                f"w: save {n} correction{'s' if n != 1 else ''} to a new file"
                if n
                else "1-5: correct labels"
            )
            if saved is not None and not source.unsaved:
                hint = f"saved {saved.name}"
            self._w[RecordingPanel].present(None, None, None, hint, snap.time_ns, idle="▶ replay")
            return
        idle = f"{key}: record trial {info.trial}"
        gaps = snap.alarms.gaps if snap.alarms is not None and elapsed is not None else None
        self._w[RecordingPanel].present(
            snap.recording if elapsed is not None else None,
            elapsed,
            app.recording_path,
            idle,
            snap.time_ns,
            gaps=gaps,
        )
        failed = snap.recording is not None and snap.recording.state == RecorderState.FAILED
        if failed and not self._failure_shown:
            self.notify(
                f"{snap.recording.message} — press {key} to close the file",
                title="recording failed",
                severity="error",
                timeout=30,
            )
        self._failure_shown = failed

    def _notify_new_events(self, snap: Snapshot) -> None:
        """A device fault shows at once, as a notification as well as in the device panel."""
        for e in snap.events:
            if self._last_event_ns is not None and e.time_ns <= self._last_event_ns:
                continue
            severity = FAULT_KINDS.get(e.kind)
            if e.device != "operator" and not severity:  # gaps, drops; notices log themselves
                log.info("%s %s: %s", e.device, e.kind, " ".join(e.message.split()))
            if e.device != "operator" and severity:
                self.notify(
                    event_sentence(e),
                    severity=severity,
                    timeout=10 if severity == "error" else 4,
                )
        if snap.events:
            self._last_event_ns = max(self._last_event_ns or 0, max(e.time_ns for e in snap.events))

    def _show_topbar(self) -> None:
        app, snap = self.app, self._snapshot
        info = app.subject
        bar = Text.assemble(
            ("walkcap ", "bold"), f"{info.subject} · {info.condition} · trial {info.trial}  "
        )
        label = snap.label if snap is not None else None
        bar.append_text(Text.assemble("true ", mode_text(label), "  "))
        elapsed = self._elapsed(snap)
        if elapsed is not None:
            bar.append(f"● REC {clock_text(elapsed)}  ", style="bold #e04040")
        source = app.source
        if isinstance(source, Playback):
            pos, duration = source.position()
            bar.append(f"{source.path.name}  ", style="bold")
            bar.append(
                f"{'▶' if source.playing else '⏸'} {clock_text(pos)} / {clock_text(duration)}  ",
                style="bold",
            )
        if self.frozen:
            bar.append(" FROZEN ", style="bold #000000 on #2f7ff0")
            bar.append("  ")
        if app.status:
            bar.append(app.status, style="bold #e04040" if app.status_is_error else "italic")
        self._w[TopBar].present(bar) if hasattr(self, "_w") else None

    # ---- keys -------------------------------------------------------------------------

    def check_action(self, action: str, parameters: tuple) -> bool | None:
        """Replay keys only in a replay; recording and the session form only live."""
        replay = isinstance(self.app.session, Playback)
        if action in ("play", "seek", "save_corrections"):
            return replay
        if action in ("record", "session_form", "check"):
            return not replay
        if action == "drill":
            return self.app.drills
        return True

    def _source_or_warn(self):
        source = self.app.source
        if source is None:
            error = self.app.start_error
            text = (
                f"the devices did not start: {error} — c retries"
                if error
                else ("the devices are still starting")
            )
            self.notify(text, severity="warning", timeout=4)
        return source

    def action_label(self, mode: str) -> None:
        source = self._source_or_warn()
        if source is None:
            return
        before = source.label
        change = source.set_label(mode)  # stamped inside, at this call: no waiting on the display
        self._keyed(change.time_ns, mode, "operator", before)
        if isinstance(source, Playback):
            pos = source.position()[0]
            self._correction_notice(
                source,
                f"correction: {MODE_NAMES[mode]} ({mode}) from {pos:.1f} s on",
                f"{mode} from {pos:.1f} s",
            )
        self._after_command()

    def _correction_notice(self, source: Playback, what: str, brief: str) -> None:
        """Each replay correction said at once, and that it is not saved yet."""
        n = len(source.corrections)
        self.app.notify(
            f"{what}; {n} correction(s) not saved yet: w writes them to a new file",
            timeout=4,
            short=f"{brief}; {n} unsaved (w saves)",
        )

    def action_undo(self) -> None:
        source = self._source_or_warn()
        if source is None:
            return
        change = source.undo_label()
        if change is None:
            self.notify("no label to undo", timeout=2)
        else:
            self._keyed(change.time_ns, change.mode, "undo", None)
            if isinstance(source, Playback):
                text = f"the last correction ({change.mode}) taken back"
                self._correction_notice(source, text, f"{change.mode} taken back")
        self._after_command()

    def action_marker(self) -> None:
        source = self._source_or_warn()
        if source is None:
            return

        pressed_ns = now_ns()  # the marker is where the operator pressed, not where they typed

        def place(note: str | None) -> None:
            if note is None:
                return
            source.add_marker(note, time_ns=pressed_ns)
            # the note is the operator's free text: on screen, not in tui.log
            self.app.notify(
                f"marker{': ' + note if note else ''}",
                timeout=3,
                logged="marker" + (" (with a note)" if note else ""),
            )

        self.app.push_screen(MarkerDialog(*self._mode_keys()), place)

    def _mode_keys(self) -> tuple[frozenset[str], str]:
        """The mode keys as configured: Textual key names, and how they read (1-5)."""
        keys = self.app.config.keys
        names = [getattr(keys, f"mode_{m.lower()}", "") or str(i + 1) for i, m in enumerate(MODES)]
        split = [k.strip() for name in names for k in name.split(",") if k.strip()]
        labels = [key_label(name) for name in names]
        text = "1-5" if labels == ["1", "2", "3", "4", "5"] else "/".join(labels)
        return frozenset(split), text

    def action_record(self) -> None:
        self.app.toggle_recording()

    def action_freeze(self) -> None:
        self.frozen = not self.frozen
        if self.frozen:
            self._timer.pause()
        else:
            self._timer.resume()
            self.refresh_view()
        self._show_topbar()

    def action_help(self) -> None:
        self.app.push_screen(HelpScreen(self.key_help()))

    def key_help(self) -> list[tuple[str, str]]:
        """(key, what it does) for this screen's bindings as configured, in BINDINGS order."""
        order = [b.action for b in self.BINDINGS]
        rows = [
            (key, active.binding)
            for key, active in self.active_bindings.items()
            if active.node is self and active.binding.action in self.HELP
        ]
        rows.sort(key=lambda kb: order.index(kb[1].action) if kb[1].action in order else len(order))
        return [(key, self.HELP.get(b.action, b.description)) for key, b in rows]

    def action_quit(self) -> None:
        self.app.request_quit()

    def action_check(self) -> None:
        self.app.retry()

    def action_drill(self, device: str, fault: str) -> None:
        self.app.inject(device, fault, seconds=2.0)

    def action_session_form(self) -> None:
        self.app.open_session_form()

    def action_save_corrections(self) -> None:
        self.app.save_corrections()

    def action_play(self) -> None:
        source = self.app.source
        if isinstance(source, Playback):
            source.toggle_play()
            self._after_command()

    def action_seek(self, direction: int) -> None:
        source = self.app.source
        if isinstance(source, Playback):
            source.seek(direction * SEEK_S)
            self._after_command()

    def _after_command(self) -> None:
        """Show the effect of a key at once (unless frozen: then only the top bar)."""
        if self.frozen:
            snap = self.app.source.snapshot() if self.app.source else None
            if snap is not None and self._snapshot is not None:
                self._snapshot.label = snap.label
            self._show_topbar()
        else:
            self.refresh_view()
