"""`walkcap tui`: the terminal UI for a data-collection session."""

from __future__ import annotations

from tui import lab_flags
from tui.commands import add_device_arguments, add_session_arguments
from tui.logfile import log_path, logging_to_file

HELP = "open the terminal UI (mock devices and the bundled model by default)"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--drills",
        action="store_true",
        help="mock devices only: keys that inject faults (ctrl+u unplugs the IMU for 2 s, "
        "ctrl+t stalls the camera for 2 s), to rehearse what the alarms show",
    )
    add_device_arguments(parser)
    add_session_arguments(parser)
    lab_flags.add_arguments(parser)


def starting_form(args, config):
    """The form the session opens with: the flags given over what is remembered for that
    subject and condition (another subject never inherits the last one's fields); the
    remembered operator unless `--operator` names one."""
    from tui.commands import subject_from_flags
    from tui.session_screen import load_remembered

    remembered = load_remembered(days=config.session.remember_days)
    if args.operator is None and remembered.operator:
        config.session.operator = remembered.operator
    base = remembered.form_for(
        args.subject or remembered.last.subject,
        args.condition or remembered.last.condition,
        config.session.recordings,
    )
    # an id given on the command line fits the study's pattern; a remembered one is checked
    # when the form is confirmed
    pattern = config.session.subject_pattern if args.subject else None
    return subject_from_flags(args, base, pattern)


def run(args, config) -> int:
    import sys

    from capture.errors import CaptureError
    from tui.app import WalkcapApp
    from tui.commands import apply_device_flags, course_condition

    apply_device_flags(args, config)
    lab_flags.apply(args, config)
    given_condition = args.condition is not None
    warning = course_condition(args, config)
    if warning:
        print(f"walkcap tui: warning: {warning}", file=sys.stderr)
    if not given_condition and args.course is None:
        args.condition = None  # the form's remembered condition stands
    subject = starting_form(args, config)
    if args.drills and (config.camera.backend != "mock" or config.imu.backend != "mock"):
        raise CaptureError("--drills injects faults into mock devices only")
    config.simulator.loop = True  # a mock subject keeps walking until the operator quits
    app = WalkcapApp(config, subject=subject, drills=args.drills)
    with logging_to_file(log_path()):
        try:
            app.run()
        finally:
            if app.session is not None:  # however the UI ended, finalise a recording
                app.session.stop()
    for line in app.trials_summary():  # what this session saved, once the screen is gone
        print(line)
    if app.start_error:
        raise CaptureError(f"the session did not start: {app.start_error}")
    return app.return_code or 0
