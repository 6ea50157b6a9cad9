"""The lab-tool flags `record` and `tui` share: LSL, remote control, live Foxglove."""

from __future__ import annotations


def add_arguments(parser) -> None:
    g = parser.add_argument_group("lab tools (all off unless asked for)")
    g.add_argument(
        "--lsl",
        action="store_true",
        help="LSL outlets: walkcap IMU, walkcap Terrain, walkcap Markers ([lsl] enabled)",
    )
    g.add_argument(
        "--lsl-record",
        action="append",
        metavar="NAME",
        help="record this LSL stream into the trial's file (repeatable; [lsl] record)",
    )
    g.add_argument(
        "--remote-control",
        action="store_true",
        help="LabRecorder-style start/stop/filename commands on 127.0.0.1:[lsl] remote_port",
    )
    g.add_argument(
        "--foxglove",
        action="store_true",
        help="live Foxglove WebSocket server on [foxglove] host:port (127.0.0.1:8765)",
    )


def apply(args, config) -> None:
    """The flags on top of the configuration file."""
    if args.lsl:
        config.lsl.enabled = True
    for name in args.lsl_record or ():
        if name not in config.lsl.record:
            config.lsl.record.append(name)
    if args.remote_control:
        config.lsl.remote_control = True
    if args.foxglove:
        config.foxglove.enabled = True
