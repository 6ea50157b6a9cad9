"""`walkcap record`: record one trial headless (mock devices by default)."""

from __future__ import annotations

import signal
import sys
import time

from tui import lab_flags
from tui.commands import count, finish_recording

HELP = "record a session headless into an MCAP file"


def add_arguments(parser) -> None:
    parser.add_argument("--camera", metavar="BACKEND", help="mock | royale")
    parser.add_argument("--imu", metavar="BACKEND", help="mock | serial")
    parser.add_argument("--port", help="IMU serial port (backend serial)")
    parser.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="seconds to record (default: until the mock course ends, or Ctrl-C)",
    )
    parser.add_argument("--fps", type=float, help="camera frame rate")
    parser.add_argument("--imu-rate", type=int, metavar="HZ", help="IMU output rate")
    parser.add_argument(
        "-o", "--out", metavar="DIR", help="recordings folder (default: [session] recordings)"
    )
    parser.add_argument("--course", choices=("indoor", "outdoor"), help="mock walk preset")
    parser.add_argument("--seed", type=int, help="mock walk seed")
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
    parser.add_argument("--model", metavar="PATH", help="classifier weights (default: bundled)")
    g = parser.add_argument_group("session metadata")
    g.add_argument("--subject", default="S01", help="pseudonymous subject id")
    g.add_argument("--condition", help="e.g. indoor / outdoor (default: the course)")
    g.add_argument(
        "--trial",
        type=count(1),
        metavar="N",
        help="trial number (default: the next free one for subject and condition in the "
        "recordings folder); one that exists is an error unless --overwrite",
    )
    g.add_argument(
        "--overwrite",
        action="store_true",
        help="record an existing --trial again: the new file supersedes the earlier one, "
        "which stays on disk and is left out of eval, train and export",
    )
    g.add_argument("--height", type=float, metavar="M", dest="height_m", help="height in metres")
    g.add_argument("--weight", type=float, metavar="KG", dest="weight_kg", help="weight in kg")
    g.add_argument("--age", type=int, help="age in years")
    g.add_argument(
        "--sex", default="", choices=("female", "male", "other"), help="(default: not given)"
    )
    g.add_argument("--amputee", action="store_true", help="the subject is an amputee")
    g.add_argument(
        "--side",
        default="",
        choices=("left", "right"),
        help="amputated side (required with --amputee)",
    )
    g.add_argument(
        "--residual-limb",
        type=float,
        metavar="CM",
        dest="residual_limb_cm",
        help="residual limb length in cm",
    )
    g.add_argument("--notes", default="", help="free text kept with the recording")
    lab_flags.add_arguments(parser)


def apply_device_flags(args, config) -> None:
    """Flags shared by record and tui: they override the configuration file."""
    from capture.config import override

    for flag, key in (
        ("camera", "camera.backend"),
        ("imu", "imu.backend"),
        ("port", "imu.port"),
        ("fps", "camera.fps"),
        ("imu_rate", "imu.rate_hz"),
        ("out", "session.recordings"),
        ("course", "simulator.course"),
        ("seed", "simulator.seed"),
        ("model", "model.path"),
    ):
        value = getattr(args, flag, None)
        if value is not None:
            override(config, key, value)
    if getattr(args, "fast", False):
        config.simulator.realtime = False


def run(args, config) -> int:
    from capture.corpus import trial_conflict
    from capture.labtools import LabTools, SessionController
    from capture.recorder import RecorderState
    from capture.session import Session, SubjectInfo

    apply_device_flags(args, config)
    lab_flags.apply(args, config)
    info = SubjectInfo(
        subject=args.subject,
        height_m=args.height_m,
        weight_kg=args.weight_kg,
        age=args.age,
        sex=args.sex,
        amputee=args.amputee,
        side=args.side,
        residual_limb_cm=args.residual_limb_cm,
        condition=args.condition or _default_condition(config),
        trial=args.trial or 1,
        notes=args.notes,
    )
    info.validate()
    existing = _on_existing(args)
    # Checked before the devices open: a refused trial costs no set-up time.
    trial_conflict(config.session.recordings, info.subject, info.condition, info.trial, existing)
    session = Session(config, auto_label=args.auto_label)
    # SIGTERM finalises the file like Ctrl-C does
    signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    stats = None
    lab = None
    remote = config.lsl.remote_control
    try:
        session.start()
        lab = LabTools(session, config, SessionController(session, info)).start()
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
        deadline = time.monotonic() + args.duration if args.duration else None
        while not session.finished.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            rec = session.snapshot().recording
            if rec is not None and rec.state == RecorderState.FAILED:
                break
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("stopping: finalising the recording", file=sys.stderr)
    finally:
        remote_log = list(lab.remote.log) if lab is not None and lab.remote is not None else []
        if lab is not None:
            lab.stop()
        stats = session.stop()
    saved = [r.removeprefix("saved ") for _, r in remote_log if r.startswith("saved ")]
    for path in saved:  # the trials the remote control started and stopped
        print(path)
    if stats is None:
        if remote and not saved:
            print("walkcap record: no trial was recorded (no remote start)", file=sys.stderr)
        return 0 if saved else 1
    snap_lat = session.snapshot().latency_ms
    print(
        f"{stats.messages} messages, {stats.bytes_written / 1e6:.1f} MB, dropped {stats.dropped}"
        + (
            f", latency p50 {snap_lat['p50']:.1f} ms p99 {snap_lat['p99']:.1f} ms"
            if snap_lat
            else ""
        ),
        file=sys.stderr,
    )
    return finish_recording("record", stats, stats.path)


def _default_condition(config) -> str:
    return config.simulator.course if config.camera.backend == "mock" else "session"


def _on_existing(args) -> str:
    """What an existing trial means: the next free number unless --trial was given."""
    from capture.corpus import NEXT_TRIAL, OVERWRITE, TRIAL_ERROR

    if args.trial is None:
        return NEXT_TRIAL
    return OVERWRITE if args.overwrite else TRIAL_ERROR
