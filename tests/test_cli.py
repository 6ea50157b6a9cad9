import os
import subprocess
import sys
from pathlib import Path

import pytest

from tui import cli

ROOT = Path(__file__).resolve().parents[1]


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


def test_unknown_flag_is_one_line_without_traceback():
    out = walkcap("record", "--no-such-flag")
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert "--no-such-flag" in out.stderr


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


def test_a_closed_pipe_is_not_an_error(tmp_path):
    """`walkcap info FILE | head -1`: the reader leaves early; no error message."""
    from recording_fixtures import write_recording

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
