import os
import subprocess
import sys
from pathlib import Path

import pytest

from tui import cli

ROOT = Path(__file__).resolve().parents[2]


def walkcap(*args: str) -> subprocess.CompletedProcess:
    """The command from this tree (the tests run in a temporary folder)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "tui.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


@pytest.mark.subprocess
def test_help_lists_every_subcommand():
    out = walkcap("--help")
    assert out.returncode == 0
    for name in cli.COMMANDS:
        assert name in out.stdout


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_every_subcommand_has_help(name, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([name, "--help"])
    assert e.value.code == 0
    assert "usage: walkcap " + name in capsys.readouterr().out


@pytest.mark.subprocess
def test_unknown_flag_is_one_line_without_traceback():
    out = walkcap("record", "--no-such-flag")
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert "--no-such-flag" in out.stderr


@pytest.mark.subprocess
def test_bad_config_is_one_line_naming_the_key(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[camera]\nfps = 'fast'\n")
    out = walkcap("--config", str(cfg), "info", "x.mcap")
    assert out.returncode == 1
    assert "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert "camera.fps" in out.stderr


def test_missing_config_file_is_a_clear_error(capsys):
    assert cli.main(["--config", "nowhere.toml", "info", "x"]) == 1
    err = capsys.readouterr().err
    assert "nowhere.toml" in err and "Traceback" not in err


def test_internal_errors_go_to_a_crash_log(monkeypatch, capsys, tmp_path):
    from tui.commands import info

    def boom(args, config):
        raise ZeroDivisionError("bug")

    monkeypatch.setattr(info, "run", boom)
    monkeypatch.delenv("WALKCAP_DEBUG", raising=False)
    assert cli.main(["info", "x"]) == 70
    err = capsys.readouterr().err
    assert "internal error" in err and "Traceback" not in err
    assert "ZeroDivisionError" in (tmp_path / ".cache" / "walkcap" / "crash.log").read_text()
    assert os.stat(tmp_path / ".cache" / "walkcap" / "crash.log").st_mode & 0o777 == 0o600


@pytest.mark.subprocess
def test_a_closed_pipe_is_not_an_error(tmp_path):
    """`walkcap info FILE | head -1`: the reader leaves early; no error message."""
    from tests.recording_fixtures import write_recording

    path = tmp_path / "r.mcap"
    write_recording(path, seconds=1.0)
    many = " ".join([f"'{path}'"] * 400)  # far more output than a pipe holds
    out = subprocess.run(
        f"'{sys.executable}' -m tui.cli info {many} | head -1",
        shell=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.stdout.strip() == str(path)
    assert "error" not in out.stderr.lower() and "Traceback" not in out.stderr


def _every_action(parser, name="walkcap"):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for verb, sub in action.choices.items():
                yield from _every_action(sub, f"{name} {verb}")
        elif not isinstance(action, argparse._HelpAction):
            yield name, action


def test_one_vocabulary_every_flag_has_help_no_empty_choice_outputs_are_o_out():
    problems = []
    for name, action in _every_action(cli.build_parser()):
        flags = action.option_strings
        if not action.help:
            problems.append(f"{name} {flags or action.dest}: no help")
        if action.choices and "" in action.choices:
            problems.append(f"{name} {flags}: an empty choice")
        if "--output" in flags or (("-o" in flags) != ("--out" in flags)):
            problems.append(f"{name} {flags}: outputs are -o/--out")
    assert problems == []


def test_an_unknown_flag_of_a_subcommand_points_to_its_help(capsys):
    with pytest.raises(SystemExit):
        cli.main(["eval", "recordings", "x.mcap", "--bogus"])
    err = capsys.readouterr().err
    assert "walkcap eval recordings --help" in err and "--bogus" in err


_WITHOUT_TORCH = """
import sys
from tui import cli
for argv in sys.argv[1:]:
    argv = argv.split()
    try:
        rc = cli.main(argv)
    except SystemExit as e:
        rc = e.code
    print("@@", argv[0], rc, "torch" in sys.modules, file=sys.stderr)
"""


@pytest.mark.subprocess
def test_commands_that_need_no_model_do_not_import_torch(tmp_path):
    """The parser holds `train`'s defaults; building it must not load torch (seconds and
    ~200 MiB on every command)."""
    from tests.recording_fixtures import write_recording

    path = tmp_path / "r.mcap"
    write_recording(path, seconds=1.0)
    commands = ["--help", "config", f"info {path}", f"export {path} -o {tmp_path / 'out'}"]
    out = subprocess.run(
        [sys.executable, "-c", _WITHOUT_TORCH, *commands],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        cwd=tmp_path,
    )
    reports = [line.split()[1:] for line in out.stderr.splitlines() if line.startswith("@@ ")]
    assert [r[0] for r in reports] == ["--help", "config", "info", "export"], out.stderr
    assert all(rc == "0" for _, rc, _ in reports), out.stderr
    assert [torch for *_, torch in reports] == ["False"] * len(commands), out.stderr
    assert any(tmp_path.joinpath("out").iterdir())  # export wrote its tables


def test_version_is_the_installed_distributions(capsys):
    from importlib import metadata

    with pytest.raises(SystemExit) as done:
        cli.main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"walkcap {metadata.version('walkcap')}"


def test_device_help_lists_the_registered_backends(monkeypatch):
    from devices import camera, imu

    monkeypatch.setitem(camera.BACKENDS, "kinect", "nowhere:Kinect")
    monkeypatch.setitem(imu.BACKENDS, "lpms", "nowhere:Lpms")
    parser = cli.build_parser()
    for command in ("record", "check", "tui"):
        sub = parser._subparsers._group_actions[0].choices[command]
        text = " ".join(sub.format_help().split())
        assert "camera backend: mock | royale | replay | kinect" in text
        assert "IMU backend: mock | serial | lpms" in text


def test_trial_and_seed_limits_are_their_owners(monkeypatch, capsys):
    from capture.live import trials
    from devices import config

    monkeypatch.setattr(trials, "TRIAL_MAX", 7)
    monkeypatch.setattr(config, "SEED_MAX", 9)
    parser = cli.build_parser()
    for flag, value, limit in (("--trial", "8", "1..7"), ("--seed", "10", "0..9")):
        with pytest.raises(SystemExit):
            parser.parse_args(["record", flag, value])
        assert f"within {limit}, got {value}" in capsys.readouterr().err
