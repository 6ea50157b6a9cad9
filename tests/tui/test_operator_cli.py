"""The operator's command line: one configuration story, the pre-flight check, gaps."""

import dataclasses
import json
import tomllib
import types

import numpy as np
import pytest

from capture import config as cfg
from capture.live import preflight
from capture.live.alarms import GAP_PERIODS, TrialAlarms
from capture.recording.gaps import stream_loss
from devices.base import DeviceStatus
from devices.config import doc_of
from tui import cli
from tui.commands import course_condition


def test_config_output_loads_back_with_every_key_documented(tmp_path):
    config = cfg.Config()
    config.camera.fps = 30.0
    config.session.operator = "RA1"
    text = cfg.documented(config)
    loaded = cfg.from_dict(tomllib.loads(text))
    assert cfg.to_dict(loaded) == cfg.to_dict(config)
    for name, section in cfg.sections():
        for key in dataclasses.fields(section):
            assert doc_of(key), f"{name}.{key.name} has no comment"
            assert f"# {doc_of(key)}" in text
    # each key's comment names its default, the effective value follows
    assert "[default: 15.0]\nfps = 30.0" in text


def test_config_command_prints_effective_and_default(tmp_path, capsys):
    path = tmp_path / "w.toml"
    path.write_text("[camera]\nfps = 45.0\n")
    assert cli.main(["config", "--config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "fps = 45.0" in out and cfg.from_dict(tomllib.loads(out)).camera.fps == 45.0
    assert cli.main(["--config", str(path), "config", "--default"]) == 0
    assert cfg.from_dict(tomllib.loads(capsys.readouterr().out)).camera.fps == 15.0


def test_config_before_or_after_the_subcommand():
    parser = cli.build_parser()
    assert parser.parse_args(["tui", "--config", "x.toml"]).config == "x.toml"
    assert parser.parse_args(["--config", "x.toml", "tui"]).config == "x.toml"
    assert parser.parse_args(["tui"]).config is None


def test_tui_takes_records_device_and_session_flags():
    parser = cli.build_parser()
    flags = "--out d --fps 30 --course outdoor --seed 3 --model m.pt --camera mock --imu mock"
    flags += " --port p --subject P07 --condition outdoor --trial 4 --operator RA1"
    for command in ("tui", "record"):
        args = parser.parse_args([command, *flags.split()])
        assert (args.out, args.fps, args.seed, args.subject, args.trial) == ("d", 30.0, 3, "P07", 4)


def test_condition_and_course_agree_or_warn():
    config = cfg.Config()
    args = types.SimpleNamespace(condition="outdoor", course=None)
    assert course_condition(args, config) is None and config.simulator.course == "outdoor"
    config = cfg.Config()
    args = types.SimpleNamespace(condition=None, course=None)
    assert course_condition(args, config) is None and args.condition == "indoor"
    config = cfg.Config()
    config.simulator.course = "indoor"
    args = types.SimpleNamespace(condition="outdoor", course="indoor")
    assert "differs" in course_condition(args, config)


def test_live_gap_count_is_the_files_count(tmp_path):
    rng = np.random.default_rng(1)
    k = np.arange(3000)
    device = (10**12 + k * 10_000_000).astype(np.int64)  # 100 Hz on the device's clock
    host = device + rng.integers(1_000_000, 3_000_000, len(k))  # jitter on the host's
    keep = np.ones(len(k), bool)
    keep[500:550] = False  # an unplug of half a second: 50 samples the device sent, lost
    keep[1800:1805] = False  # 5 more
    host[2500:] += int(0.2e9)  # the host stalled 0.2 s: late, nothing lost
    items = [(int(k[i]), int(device[i]), int(host[i])) for i in np.nonzero(keep)[0]]
    alarms = TrialAlarms(tmp_path, {"imu": 0.01})
    alarms.new_trial()
    for seq, dev, t in items:
        alarms.sample("imu", seq, dev, t)
    counter = alarms.counters["imu"]
    loss = stream_loss(items, 0.01, 1 << 16)
    assert counter.count == len(loss.gaps) == 2 and loss.missing == 55
    assert counter.longest_s == pytest.approx(loss.longest_s) == pytest.approx(0.51)
    assert len(loss.late) == len(counter.loss.loss.late) == 1
    assert GAP_PERIODS == 3.0


def test_a_silent_stream_alarms_while_it_lasts(tmp_path):
    alarms = TrialAlarms(tmp_path)
    alarms.new_trial()
    for i in range(50):
        alarms.sample("imu", i, i * 10_000_000, i * 10_000_000)
    state = alarms.state(49 * 10_000_000 + 1_000_000_000, None, [])
    assert any("IMU: no data for 1.0 s" in a.text and a.level == "error" for a in state.alarms)
    for i in range(10):  # unplugged: the device counted on, the samples are lost
        t = 49 * 10_000_000 + 1_000_000_000 + i * 10_000_000
        alarms.sample("imu", 149 + i, t, t)
    state = alarms.state(49 * 10_000_000 + 1_095_000_000, None, [])
    assert state.gaps["imu"] == 1 and state.missing["imu"] == 99
    assert any("gap of 1.00 s ended" in a.text for a in state.alarms)


def test_a_host_stall_alarms_as_late_not_as_a_gap(tmp_path):
    alarms = TrialAlarms(tmp_path)
    alarms.new_trial()
    for i in range(100):  # every sample there, the last 50 delivered 0.5 s late
        alarms.sample("imu", i, i * 10_000_000, i * 10_000_000 + (500_000_000 if i >= 50 else 0))
    state = alarms.state(99 * 10_000_000 + 600_000_000, None, [])
    assert state.gaps["imu"] == 0 and state.late["imu"] == 1
    texts = [a.text for a in state.alarms]
    assert any("0.51 s late (the computer stalled), nothing lost" in t for t in texts)
    assert not any(t.startswith("gaps this trial") for t in texts)
    assert "late deliveries this trial: camera 0, IMU 1" in texts


def test_low_disk_and_a_filling_queue_alarm(tmp_path):
    alarms = TrialAlarms(tmp_path)
    stats = types.SimpleNamespace(bytes_per_s=1e12, queue_depth=400, queue_size=512)
    texts = [a.text for a in alarms.state(10**10, stats, []).alarms]
    assert any(t.startswith("disk: 0 min") for t in texts)
    assert any("writer queue 78 % full" in t for t in texts)


def _status(**kw):
    base = dict(backend="mock", state="ok", configured_rate_hz=100.0, measured_rate_hz=99.0)
    return DeviceStatus(**{**base, **kw})


def test_device_item_names_id_rates_drift_and_fails_when_slow():
    status = _status(details={"device_id": "0388", "firmware": "1.8", "drift_ppm": 40.0})
    item = preflight.device_item("imu", status, {"p99_ms": 0.2})
    assert item.ok and "firmware 1.8" in item.summary and "clock drift +40 ppm" in item.summary
    assert "sync error p99 0.2 ms" in item.summary and "rate 99.0 of 100 Hz" in item.summary
    slow = preflight.device_item("imu", _status(measured_rate_hz=50.0))
    assert not slow.ok and "below 80%" in slow.reason
    lost = preflight.device_item("camera", _status(state="lost", message="unplugged"))
    assert not lost.ok and lost.reason == "lost: unplugged"
    assert not preflight.device_item("camera", None).ok


def test_disk_item_fails_below_ten_minutes(tmp_path):
    assert preflight.disk_item(tmp_path, 1.0).ok
    item = preflight.disk_item(tmp_path, 1e12)
    assert not item.ok and "below 10 min" in item.reason


def test_model_item_probe_must_be_finite():
    class Broken:
        metadata = {"weights_sha256": "ab" * 32}
        classes = ("LG", "US", "DS", "UR", "DR")
        path = "x.pt"

        def predict(self, image):
            return np.full(5, np.nan)

    item = preflight.model_item(Broken(), "x.pt")
    assert not item.ok and item.reason == "probe inference is not finite"


def test_check_fails_with_the_reason_on_a_broken_model(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    code = cli.main(["check", "--json", "--model", str(bad), "--out", str(tmp_path / "o")])
    report = json.loads(capsys.readouterr().out)
    assert code == 1 and not report["ok"]
    model = next(i for i in report["items"] if i["name"] == "model")
    assert not model["ok"] and model["reason"]
    assert next(i for i in report["items"] if i["name"] == "output folder")["ok"]
