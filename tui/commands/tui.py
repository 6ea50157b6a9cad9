"""`walkcap tui`: the terminal UI for a data-collection session."""

HELP = "open the terminal UI (mock devices and the bundled model by default)"


def add_arguments(parser) -> None:
    parser.add_argument("--camera", metavar="BACKEND", help="camera backend: mock | royale | replay")
    parser.add_argument("--imu", metavar="BACKEND", help="IMU backend: mock | serial")
    parser.add_argument("--port", help="serial port of the IMU (backend serial)")


def run(args, config) -> int:
    from capture.config import override
    from tui.app import WalkcapApp

    if args.camera:
        override(config, "camera.backend", args.camera)
    if args.imu:
        override(config, "imu.backend", args.imu)
    if args.port:
        override(config, "imu.port", args.port)
    WalkcapApp(config).run()
    return 0
