"""One module per `walkcap` subcommand: HELP, add_arguments(parser), run(args, config)."""

import argparse
from collections.abc import Callable

from devices.camera import BACKENDS as CAMERA_BACKENDS
from devices.imu import BACKENDS as IMU_BACKENDS
from tui.subject import SUBJECT_FIELDS


def trial_max() -> int:
    """capture.live.trials' TRIAL_MAX, imported when a value is parsed: --help stays fast."""
    from capture.live.trials import TRIAL_MAX

    return TRIAL_MAX


def seed_max() -> int:
    """devices.config's SEED_MAX, imported when a value is parsed: --help stays fast."""
    from devices.config import SEED_MAX

    return SEED_MAX


def count(minimum: int, maximum: int | Callable[[], int] | None = None):
    """An argparse type: an integer of at least `minimum` (and at most `maximum`, or what
    `maximum()` returns when a value is parsed), else a one-line usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        high = maximum() if callable(maximum) else maximum
        if value < minimum or (high is not None and value > high):
            valid = f">= {minimum}" if high is None else f"within {minimum}..{high}"
            raise argparse.ArgumentTypeError(f"must be {valid}, got {value}")
        return value

    return parse


def positive(unit: str, *, zero: bool = False, maximum: float | None = None):
    """An argparse type: a finite number of `unit` above 0 (at least 0 with `zero`; at most
    `maximum`), else a one-line usage error."""
    import math

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {unit}, got {text!r}") from None
        low = value >= 0 if zero else value > 0
        if math.isfinite(value) and low and (maximum is None or value <= maximum):
            return value
        if maximum is not None:
            valid = f"expected {'0 <=' if zero else '0 <'} {unit} <= {maximum:g}"
        elif zero:
            valid = f"must be a number of {unit} >= 0"
        else:
            valid = f"must be a positive number of {unit}"
        raise argparse.ArgumentTypeError(f"{valid}, got {text}")

    return parse


seconds = positive("seconds")


_KINDS = {float: "a number", int: "an integer", str: "text"}


def _held_to(check, parse):
    """An argparse type: the text parsed, then held to `check(value)`; a WalkcapError it
    raises is a one-line usage error."""

    def value_of(text: str):
        from devices.errors import WalkcapError

        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {_KINDS[parse]}, got {text!r}") from None
        try:
            check(value)
        except WalkcapError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return value

    return value_of


def config_value(dotted: str, parse=float):
    """An argparse type: a value for the configuration key `dotted` ("camera.fps"), held to
    the configuration's own type and range check; out of range, a one-line usage error."""

    def check(value) -> None:
        from capture.config import Config, override

        override(Config(), dotted, value)

    return _held_to(check, parse)


def subject_value(field: str, parse=str):
    """An argparse type: a value of the session form's `field`, held to the form's own check
    (capture.live.trials.SubjectInfo.validate); out of range, a one-line usage error."""

    def check(value) -> None:
        import dataclasses

        from capture.live.trials import SubjectInfo

        dataclasses.replace(SubjectInfo(), **{field: value}).validate()

    return _held_to(check, parse)


def folder(text: str) -> str:
    """An argparse type: a folder to write into, existing or not; a file there is a usage
    error that says so (not "not writable: File exists" at the pre-flight check)."""
    import os

    path = os.path.expanduser(text)
    if os.path.exists(path) and not os.path.isdir(path):
        raise argparse.ArgumentTypeError(f"{text} is a file, not a folder: give a folder")
    parent = os.path.dirname(os.path.abspath(path))
    while parent and not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if parent and not os.path.isdir(parent):
        raise argparse.ArgumentTypeError(f"{parent} is a file, so {text} cannot be a folder")
    return text


def finish_recording(command: str, stats, path) -> int:
    """Print the file path last (scripts take it); a failed recording is one error line."""
    from capture.recording.writer import RecorderState

    if stats.state == RecorderState.FAILED:
        from tui.cli import error_line

        error_line(command, stats.message)
        print(path)
        return 1
    print(path)
    return 0


def add_recordings_argument(parser, help: str = "recordings, or folders of them") -> None:
    """The recordings a corpus command reads: files, and folders searched for them."""
    parser.add_argument("files", nargs="+", metavar="FILE|DIR", help=help)


def add_preset_argument(parser) -> None:
    """The course preset of simulated sessions (`synth`, `eval-model`)."""
    parser.add_argument(
        "--preset",
        choices=("indoor", "outdoor", "both"),
        default="both",
        help="course preset of the sessions; both alternates indoor and outdoor (default: both)",
    )


def add_device_arguments(parser) -> None:
    """The device and model flags `record`, `check` and `tui` share (they override the config
    file); the backends listed are the registries' (capture has registered its own by now)."""
    g = parser.add_argument_group("devices")
    g.add_argument(
        "--camera",
        type=config_value("camera.backend", str),
        metavar="BACKEND",
        help="camera backend: " + " | ".join(CAMERA_BACKENDS),
    )
    g.add_argument(
        "--imu",
        type=config_value("imu.backend", str),
        metavar="BACKEND",
        help="IMU backend: " + " | ".join(IMU_BACKENDS),
    )
    g.add_argument("--port", help="IMU serial port (backend serial)")
    g.add_argument("--fps", type=config_value("camera.fps"), help="camera frame rate")
    g.add_argument(
        "--imu-rate", type=config_value("imu.rate_hz", int), metavar="HZ", help="IMU output rate"
    )
    g.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        type=folder,
        help="recordings folder (default: [session] recordings)",
    )
    g.add_argument("--course", choices=("indoor", "outdoor"), help="mock walk preset")
    g.add_argument("--seed", type=count(0, seed_max), help="mock walk seed")
    g.add_argument("--model", metavar="PATH", help="classifier weights (default: bundled)")
    g.add_argument("--operator", help="who runs the session (written into each recording)")


def add_session_arguments(parser) -> None:
    """The session form's fields as flags (`record` and `tui` share them); unset: not given."""
    g = parser.add_argument_group("session metadata")
    g.add_argument(
        "--subject",
        type=subject_value("subject"),
        help="pseudonymous subject id (default: S01)",
    )
    g.add_argument(
        "--condition",
        type=subject_value("condition"),
        help="e.g. indoor / outdoor (default: the mock course)",
    )
    g.add_argument(
        "--trial",
        type=count(1, trial_max),
        metavar="N",
        help="trial number (default: the next free one for subject and condition in the "
        "recordings folder); `record` refuses one that exists unless --overwrite, the UI "
        "moves on to the next free number and says so",
    )
    for flag, name, parse, metavar, what in (
        ("--height", "height_m", float, "M", "height in metres"),
        ("--weight", "weight_kg", float, "KG", "weight in kg"),
        ("--age", "age", int, None, "age in years"),
    ):
        g.add_argument(flag, type=subject_value(name, parse), metavar=metavar, dest=name, help=what)
    g.add_argument("--sex", choices=("female", "male", "other"), help="(default: not given)")
    g.add_argument("--amputee", action="store_true", default=None, help="the subject is an amputee")
    g.add_argument(
        "--side", choices=("left", "right"), help="amputated side (required with --amputee)"
    )
    g.add_argument(
        "--residual-limb",
        type=float,
        metavar="CM",
        dest="residual_limb_cm",
        help="residual limb length in cm",
    )
    g.add_argument(
        "--notes",
        help="free text about the trial, kept with the recording: never names, dates of "
        "birth or places",
    )


SESSION_FLAGS = ("subject", "condition", "trial", *SUBJECT_FIELDS)


def apply_device_flags(args, config) -> None:
    """The device flags given override the configuration."""
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
        ("operator", "session.operator"),
    ):
        value = getattr(args, flag, None)
        if value is not None:
            override(config, key, value, flag="--" + flag.replace("_", "-"))


def subject_from_flags(args, base, pattern: str | None = None):
    """`base` (a SubjectInfo) with the session flags given on top, validated; `pattern`: the
    subject id must fit it ([session] subject_pattern)."""
    import dataclasses

    given = {k: getattr(args, k) for k in SESSION_FLAGS if getattr(args, k, None) is not None}
    info = dataclasses.replace(base, **given)
    info.validate(pattern)
    return info


def course_condition(args, config) -> str | None:
    """Make a mock walk's course and the condition agree; a warning when they cannot.

    `--condition outdoor` alone walks the outdoor course; `--course` alone names the
    condition. Returns the warning to print, or None.
    """
    if config.camera.backend != "mock":
        return None
    condition, course = args.condition, args.course
    if condition is None:
        args.condition = config.simulator.course
        return None
    if course is None and condition in ("indoor", "outdoor"):
        config.simulator.course = condition
        return None
    if condition != config.simulator.course:
        return (
            f"condition {condition!r} differs from the mock course "
            f"{config.simulator.course!r} (the file records both)"
        )
    return None


def add_cluster_argument(parser, work: str) -> None:
    """`--cluster ADDRESS|local`: `work` as one task each on a Ray cluster
    (capture.corpus.cluster)."""
    parser.add_argument(
        "--cluster",
        metavar="ADDRESS|local",
        help=f"run {work} as Ray tasks: 'local' starts a cluster on this machine's cores, "
        "an address (host:port) joins a running one; every node needs walkcap and the "
        "files at the same paths (default: this process)",
    )
