"""Values are checked at the boundary: every wrong value in the configuration file or a
flag is one line naming the key or flag and the valid range, before any device opens."""

from __future__ import annotations

import pytest

from capture import config as C
from capture.errors import ConfigError
from tui import cli


def run(argv, capsys) -> tuple[int, str]:
    """Exit status and the one line on stderr (argparse's usage errors exit too)."""
    try:
        code = cli.main(argv)
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return code, lines[0]


@pytest.fixture
def no_devices(monkeypatch):
    """Any device opening fails the test: validation comes first."""
    import capture.live.session

    def refuse(*args, **kwargs):
        raise AssertionError("a session was created before the values were checked")

    monkeypatch.setattr(capture.live.session.Session, "__init__", refuse)


@pytest.mark.parametrize(
    "toml, key, valid",
    [
        ("[camera]\nfps = 0", "camera.fps", "fps <= 45"),
        ("[camera]\nfps = nan", "camera.fps", "fps <= 45"),
        ("[camera]\nfps = inf", "camera.fps", "fps <= 45"),
        ("[camera]\nfps = -5", "camera.fps", "fps <= 45"),
        ("[camera]\nfps = 1e9", "camera.fps", "fps <= 45"),
        ("[camera]\nfps = 46", "camera.fps", "fps <= 45"),
        ("[mounting]\npitch_deg = nan", "mounting.pitch_deg", "-180 to 180"),
        ('[model]\ndevice = "tpu"', "model.device", "auto | cpu | cuda"),
        ("[imu]\nbaudrate = 0", "imu.baudrate", "115200"),
        ("[imu]\nrate_hz = 0", "imu.rate_hz", "1 to 2000"),
        ("[fusion]\ntransition = [[1.0, 0.0], [0.5]]", "fusion.transition", "5 rows of 5"),
        ("[fusion]\nwindow = 0", "fusion.window", "1 to 1000"),
        ("[preprocess]\ncell_m = -0.01", "preprocess.cell_m", "0 < cell_m"),
        ("[session]\nrealtime_priority = 100", "session.realtime_priority", "0 (normal"),
    ],
)
def test_a_value_out_of_range_in_the_file_is_one_line(
    tmp_path, capsys, no_devices, toml, key, valid
):
    path = tmp_path / "walkcap.toml"
    path.write_text(toml + "\n")
    code, line = run(["--config", str(path), "record", "--duration", "1"], capsys)
    assert code == 1 and key in line and valid in line and str(path) in line


@pytest.mark.parametrize(
    "content, what",
    [
        ("[camera]\nfps = 15.0 # caf\u00e9\n".encode("latin-1"), "not UTF-8"),
        ("[camera]\nfps = 15.0\n".encode("utf-16"), "not UTF-8"),
    ],
    ids=["latin-1", "utf-16"],
)
def test_a_config_that_is_not_utf8_is_one_line(tmp_path, capsys, no_devices, content, what):
    path = tmp_path / "walkcap.toml"
    path.write_bytes(content)
    code, line = run(["--config", str(path), "record", "--duration", "1"], capsys)
    assert code == 1 and what in line and str(path) in line


@pytest.mark.parametrize(
    "argv, name",
    [
        (["record", "--fps", "0"], "--fps"),
        (["record", "--fps", "nan"], "--fps"),
        (["record", "--fps", "-5"], "--fps"),
        (["record", "--fps", "100000"], "--fps"),
        (["record", "--fps", "fast"], "--fps"),
        (["tui", "--fps", "0"], "--fps"),
        (["record", "--imu-rate", "0"], "--imu-rate"),
        (["record", "--imu-rate", "1.5"], "--imu-rate"),
        (["record", "--camera", "kinect"], "--camera"),
        (["record", "--imu", "bno055"], "--imu"),
        (["record", "--duration", "-5"], "--duration"),
        (["record", "--duration", "0"], "--duration"),
        (["record", "--duration", "nan"], "--duration"),
        (["record", "--subject", "Jo Doe"], "--subject"),
        (["tui", "--subject", "Jo Doe"], "--subject"),
        (["record", "--condition", "a b"], "--condition"),
        (["record", "--height", "180"], "--height"),
        (["record", "--weight", "2"], "--weight"),
        (["record", "--age", "0"], "--age"),
        (["record", "--age", "forty"], "--age"),
        (["imu", "stream", "mock", "--rate", "0"], "--rate"),
        (["imu", "stream", "mock", "--baudrate", "0"], "--baudrate"),
        (["imu", "set-baud", "/dev/null", "7"], "baud"),
        (["imu", "emulate", "--rate", "0"], "--rate"),
        (["imu", "emulate", "--drift-ppm", "1e9"], "--drift-ppm"),
        (["imu", "emulate", "--jitter-ms", "-1"], "--jitter-ms"),
        (["eval", "scores", "x.csv", "--sweep-delay", "1000000"], "--sweep-delay"),
        (["eval", "scores", "x.csv", "--fps", "0"], "--fps"),
        (["bench", "--seconds", "0"], "--seconds"),
        (["bench", "--soak", "-1"], "--soak"),
        (["bench", "--cluster", "local", "--sessions", "1"], "--sessions"),
        (["bench", "--cluster", "local", "--rounds", "0"], "--rounds"),
        (["replay", "x.mcap", "--speed", "0"], "--speed"),
        (["synth", "-o", "out", "--imu-error-deg", "-1"], "--imu-error-deg"),
    ],
)
def test_a_flag_out_of_range_is_a_usage_error(capsys, no_devices, argv, name):
    """argparse's usage error: exit status 2, one line naming the flag and its command's help."""
    code, line = run(argv, capsys)
    assert code == 2 and f"argument {name}: " in line
    assert line.endswith(
        f"(see 'walkcap {' '.join(argv[: 2 if argv[0] in ('imu', 'eval') else 1])} --help')"
    )


def test_the_checked_flags_keep_good_values():
    args = cli.build_parser().parse_args(
        "record --camera replay --imu serial --fps 30 --imu-rate 400 --subject S02 "
        "--condition outdoor --height 1.8 --weight 70 --age 40".split()
    )
    assert (args.camera, args.imu, args.fps, args.imu_rate) == ("replay", "serial", 30.0, 400)
    assert (args.subject, args.condition, args.height_m, args.weight_kg, args.age) == (
        "S02",
        "outdoor",
        1.8,
        70.0,
        40,
    )


def test_override_keeps_the_old_value_when_it_refuses():
    config = C.Config()
    with pytest.raises(ConfigError, match=r"--fps \(camera.fps\) = 0.0"):
        C.override(config, "camera.fps", 0, flag="--fps")
    assert config.camera.fps == 15.0
    C.override(config, "camera.fps", 45)
    assert config.camera.fps == 45.0


def test_the_defaults_and_a_saved_config_pass(tmp_path):
    path = C.save(C.Config(), tmp_path / "walkcap.toml")
    assert C.load(path).camera.fps == 15.0
