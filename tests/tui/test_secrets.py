"""A secret the configuration sets (`[lsl] remote_token`) shows nowhere: not in `walkcap
config` (whose output still loads), the recording's copy, `--json` output, error lines,
the terminal log, tui.log, the crash log, nor the remote control's log and events (what
the screen's notice line, the terminal log and the recording's /events show)."""

import json
import logging
import tomllib

import pytest

from capture import config as config_mod
from capture.labtools.remote import RemoteControl
from capture.recording.writer import Recorder
from tui import cli
from tui.logfile import REDACTOR, logging_to_file

TOKEN = "s3cret-t0ken-77"


@pytest.fixture(autouse=True)
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("WALKCAP_DEBUG", raising=False)
    saved = list(REDACTOR.secrets)
    yield tmp_path
    REDACTOR.secrets = saved


@pytest.fixture
def lab_toml(tmp_path):
    path = tmp_path / "walkcap.toml"
    path.write_text(f'[lsl]\nremote_control = true\nremote_token = "{TOKEN}"\n')
    return path


def test_walkcap_config_prints_the_token_redacted_and_still_loads(lab_toml, capsys):
    assert cli.main(["--config", str(lab_toml), "config"]) == 0
    out = capsys.readouterr().out
    assert TOKEN not in out
    assert 'remote_token = ""  # set, not shown' in out
    assert tomllib.loads(out)["lsl"]["remote_token"] == ""
    assert tomllib.loads(out)["lsl"]["remote_control"] is True  # the rest as it is


def test_a_bad_token_value_is_not_echoed_in_the_error(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[lsl]\nremote_token = 770077\n")
    assert cli.main(["--config", str(path), "config"]) == 1
    err = capsys.readouterr().err
    assert "lsl.remote_token: expected a string" in err and "770077" not in err


def test_no_log_error_or_crash_log_says_the_token(lab_toml, capsys, monkeypatch, home):
    from tui.commands import info

    def leaky(args, config):
        logging.getLogger("capture.labtools.remote").warning("the token is %s", TOKEN)
        raise RuntimeError(f"broken with {TOKEN}")

    monkeypatch.setattr(info, "run", leaky)
    assert cli.main(["--config", str(lab_toml), "info", "x"]) == 70
    captured = capsys.readouterr()
    assert "internal error" in captured.err and "<secret>" in captured.err
    assert TOKEN not in captured.err + captured.out
    crash = (home / ".cache" / "walkcap" / "crash.log").read_text()
    assert "RuntimeError" in crash and TOKEN not in crash

    def user_error(args, config):
        raise config_mod.ConfigError(f"refused {TOKEN}")

    monkeypatch.setattr(info, "run", user_error)
    assert cli.main(["--config", str(lab_toml), "info", "x"]) == 1
    assert TOKEN not in capsys.readouterr().err


def test_tui_log_keeps_the_token_out(lab_toml, home):
    REDACTOR.secrets = config_mod.secrets_of(config_mod.load(str(lab_toml)))
    path = home / "tui.log"
    with logging_to_file(str(path)):
        logging.getLogger("capture.live.session").warning("remote said %s", TOKEN)
        try:
            raise ValueError(TOKEN)
        except ValueError:
            logging.getLogger("tui.app").exception("failed")
    text = path.read_text()
    assert "remote said <secret>" in text and "ValueError" in text and TOKEN not in text


def test_json_outputs_and_the_recordings_copy_leave_it_out(lab_toml, tmp_path, capsys):
    config = config_mod.load(str(lab_toml))
    path = tmp_path / "trial.mcap"
    attached = config_mod.dumps(config, secrets=False)
    with Recorder(path, metadata={}, attachments={"walkcap.toml": attached.encode()}):
        pass
    assert TOKEN not in path.read_bytes().decode("latin-1")
    assert cli.main(["--config", str(lab_toml), "info", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    json.loads(out)
    assert TOKEN not in out


class _Controller:
    def remote_start(self, request):
        return "recording"

    def remote_stop(self):
        return "saved"


def test_the_remote_controls_log_and_events_never_carry_the_token(caplog):
    events = []
    remote = RemoteControl(_Controller(), port=0, token=TOKEN, on_event=events.append)
    with caplog.at_level(logging.INFO, logger="capture.labtools.remote"):
        remote.handle(f"token {TOKEN}")  # sent again once trusted: an unknown command
        remote.handle(f"token {TOKEN[:-1]}x")  # a mistyped token is nearly the token
        remote.handle(f"filename {{root:{TOKEN}}}")
    said = caplog.text + repr(remote.log) + repr([(e.message, e.details) for e in events])
    assert events and TOKEN not in said and TOKEN[:-1] not in said
    assert "token <secret>" in said
