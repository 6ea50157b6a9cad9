"""`walkcap check`: the pre-flight check headless (devices, model, folder, disk)."""

from __future__ import annotations

import json

from tui.commands import add_device_arguments

HELP = "pre-flight check: devices, model, output folder, free disk (non-zero exit on a failure)"


def add_arguments(parser) -> None:
    parser.add_argument("--json", action="store_true", help="the report as JSON on stdout")
    parser.add_argument(
        "--probe",
        type=float,
        default=2.0,
        metavar="S",
        help="seconds of probe recording that measure the write rate (0: none)",
    )
    add_device_arguments(parser)


def run(args, config) -> int:
    from capture.live import preflight
    from capture.live.session import Session
    from tui.commands import apply_device_flags

    apply_device_flags(args, config)
    session = Session(config)
    try:
        try:
            session.start()
        except Exception as e:  # the report names what failed; a bug still goes up
            from devices.errors import WalkcapError

            if not isinstance(e, (WalkcapError, OSError)):
                raise
            report = preflight.start_failure(config, e)
        else:
            report = preflight.run(session, probe_s=args.probe)
    finally:
        session.stop()
    if args.json:
        print(json.dumps(report.to_dict(), indent=2, default=str))
    else:
        print("\n".join(report.lines()))
        print("pre-flight: " + ("ok" if report.ok else f"FAILED ({report.reason()})"))
    return 0 if report.ok else 1
