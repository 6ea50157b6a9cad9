"""`walkcap tui`: the terminal UI for a data-collection session."""

from __future__ import annotations

import contextlib
import logging
import os

from tui import lab_flags

HELP = "open the terminal UI (mock devices and the bundled model by default)"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--camera", metavar="BACKEND", help="camera backend: mock | royale | replay"
    )
    parser.add_argument("--imu", metavar="BACKEND", help="IMU backend: mock | serial")
    parser.add_argument("--port", help="serial port of the IMU (backend serial)")
    lab_flags.add_arguments(parser)


def log_path() -> str:
    return os.path.join(os.path.expanduser("~"), ".cache", "walkcap", "tui.log")


@contextlib.contextmanager
def logging_to_file(path: str):
    """While the UI owns the terminal, log lines go to a file instead of stderr."""
    root = logging.getLogger()
    saved = root.handlers[:]
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        handler: logging.Handler = logging.FileHandler(path)
    except OSError:
        handler = logging.NullHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.handlers = [handler]
    try:
        yield
    finally:
        root.handlers = saved
        handler.close()


def run(args, config) -> int:
    from capture.config import override
    from tui.app import WalkcapApp

    if args.camera:
        override(config, "camera.backend", args.camera)
    if args.imu:
        override(config, "imu.backend", args.imu)
    if args.port:
        override(config, "imu.port", args.port)
    lab_flags.apply(args, config)
    config.simulator.loop = True  # a mock subject keeps walking until the operator quits
    app = WalkcapApp(config)
    with logging_to_file(log_path()):
        try:
            app.run()
        finally:
            if app.session is not None:  # however the UI ended, finalise a recording
                app.session.stop()
    if app.start_error:
        from capture.errors import CaptureError

        raise CaptureError(f"the session did not start: {app.start_error}")
    return app.return_code or 0
