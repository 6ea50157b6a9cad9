"""`walkcap record`: record one trial headless (mock devices by default)."""

from __future__ import annotations

import signal
import sys
import time

from tui import lab_flags
from tui.commands import (
    add_device_arguments,
    add_session_arguments,
    apply_device_flags,
    course_condition,
    finish_recording,
    seconds,
    subject_from_flags,
)

HELP = "record a session headless into an MCAP file"
STATUS_EVERY_S = 0.5


def add_arguments(parser) -> None:
    parser.add_argument(
        "--duration",
        type=seconds,
        metavar="S",
        help="seconds to record (a mock course loops to fill them; default: until the mock "
        "course ends, or Ctrl-C)",
    )
    parser.add_argument(
        "--fast",
        action="store_true",
        help="mock camera as fast as the pipeline runs (not real time)",
    )
    parser.add_argument(
        "--auto-label",
        action="store_true",
        help="labels from the simulator's truth (unattended mock runs)",
    )
    add_device_arguments(parser)
    add_session_arguments(parser)
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="record an existing --trial again: the new file supersedes the earlier one, "
        "which stays on disk and is left out of eval, train and export",
    )
    lab_flags.add_arguments(parser)


def status_line(elapsed_s: float, total_s: float | None, snap) -> str:
    """One line for a terminal: elapsed / total, frames, drops, gaps, size."""
    from tui.widgets.recording_panel import clock_text, human_bytes

    rec = snap.recording
    total = f" / {clock_text(total_s)}" if total_s else ""
    drops = (rec.dropped if rec is not None else 0) + sum(
        s.dropped for s in (snap.camera, snap.imu) if s is not None
    )
    gaps = snap.alarms.gaps if snap.alarms is not None else {}
    size = human_bytes(rec.bytes_written if rec is not None else 0)
    line = (
        f"REC {clock_text(elapsed_s)}{total}  frames {snap.frames}  drops {drops}  "
        f"gaps camera {gaps.get('camera', 0)} IMU {gaps.get('imu', 0)}  size {size}"
    )
    alarms = snap.alarms.alarms if snap.alarms is not None else []
    return line + (f"  ! {alarms[0].text}" if alarms else "")


def run(args, config) -> int:
    from capture.live.trials import SubjectInfo

    # the subject id first: a name is refused before the session's libraries load
    subject_from_flags(
        args, SubjectInfo(condition=args.condition or "session"), config.session.subject_pattern
    )
    from capture.labtools.connections import LabTools, SessionController
    from capture.live.session import Session
    from capture.recording.naming import trial_conflict
    from capture.recording.writer import RecorderState

    apply_device_flags(args, config)
    lab_flags.apply(args, config)
    warning = course_condition(args, config)
    if warning:
        print(f"walkcap record: warning: {warning}", file=sys.stderr)
    if args.fast:
        config.simulator.realtime = False
    if args.duration and config.camera.backend == "mock":
        config.simulator.loop = True  # the walk goes on for as long as asked, as in the UI
    info = subject_from_flags(
        args, SubjectInfo(condition=args.condition or "session"), config.session.subject_pattern
    )
    existing = _on_existing(args)
    # Checked before the devices open: a refused trial costs no set-up time.
    trial_conflict(config.session.recordings, info.subject, info.condition, info.trial, existing)
    session = Session(config, auto_label=args.auto_label)
    # SIGTERM finalises the file like Ctrl-C does
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    tty = sys.stderr.isatty()
    stats = None
    lab = None
    remote = config.lsl.remote_control
    try:
        session.start()
        controller = SessionController(session, info, config.session.subject_pattern)
        lab = LabTools(session, config, controller).start()
        for line in lab.describe():
            print(line, file=sys.stderr)
        for problem in lab.problems:
            print(f"walkcap record: {problem}", file=sys.stderr)
        if remote:  # the experiment script says when: start, stop, start, ...
            print("waiting for the remote control's start (Ctrl-C ends)", file=sys.stderr)
        else:
            path = session.start_recording(info, existing)
            if session.trial_notice:
                print(f"walkcap record: {session.trial_notice}", file=sys.stderr)
            print(f"recording {path}", file=sys.stderr)
        started = time.monotonic()
        deadline = started + args.duration if args.duration else None
        shown = 0.0
        while not session.finished.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            snap = session.snapshot()
            if snap.recording is not None and snap.recording.state == RecorderState.FAILED:
                break
            if tty and now - shown >= STATUS_EVERY_S and snap.recording is not None:
                shown = now
                line = status_line(now - started, args.duration, snap)
                print(f"\r\x1b[K{line}", end="", file=sys.stderr, flush=True)
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("\nstopping: finalising the recording", file=sys.stderr)
    finally:
        if tty:
            print(file=sys.stderr)
        saved = list(lab.remote.saved) if lab is not None and lab.remote is not None else []
        if lab is not None:
            lab.stop()
        stats = session.stop()
    for path in saved:  # the trials the remote control started and stopped
        print(path)
    if stats is None:
        if remote and not saved:
            print("walkcap record: no trial was recorded (no remote start)", file=sys.stderr)
        return 0 if saved else 1
    snap_lat = session.snapshot().latency_ms
    gaps, late = session.alarms.trial_gaps, session.alarms.trial_late
    print(
        f"{stats.duration_s:.1f} s, {stats.messages} messages, "
        f"{stats.bytes_written / 1e6:.1f} MB, dropped {stats.dropped}, "
        f"derived shed {stats.shed}, "
        f"gaps camera {gaps.get('camera', 0)} IMU {gaps.get('imu', 0)}, "
        f"late deliveries camera {late.get('camera', 0)} IMU {late.get('imu', 0)}"
        + (
            f", pipeline latency median {snap_lat['p50']:.1f} ms p99 {snap_lat['p99']:.1f} ms"
            if snap_lat
            else ""
        ),
        file=sys.stderr,
    )
    return finish_recording("record", stats, stats.path)


def _on_existing(args) -> str:
    """What an existing trial means: the next free number unless --trial was given."""
    from capture.recording.naming import NEXT_TRIAL, OVERWRITE, TRIAL_ERROR

    if args.trial is None:
        return NEXT_TRIAL
    return OVERWRITE if args.overwrite else TRIAL_ERROR
