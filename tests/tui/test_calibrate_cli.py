"""`walkcap calibrate`: printed, written, refused."""

import json
import re

import pytest

from tests import terrain_raycast as tr
from tests.capture.labtools.test_mounting import FakeCamera, FakeImu
from tests.inference.test_calibration import TRUE_MOUNTING, standing


@pytest.fixture
def devices(monkeypatch):
    from capture.labtools import mounting

    def use(xyz, conf, quats):
        camera, imu = FakeCamera(xyz, conf), FakeImu(quats)
        monkeypatch.setattr(mounting, "open_devices", lambda config: (camera, imu))
        return camera, imu

    return use


def test_calibrate_command_writes_the_mounting(devices, tmp_path, capsys):
    from capture import config as cfg
    from tui import cli

    xyz, conf, quats = standing(count=2, sway_deg=0.0)
    camera, imu = devices(xyz, conf, quats)
    path = tmp_path / "walkcap.toml"
    path.write_text("[camera]\nfps = 30.0\n[mounting]\npitch_deg = 35.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "0.3"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"pitch\s+\+35\.00 ->\s+\+38\.(49|50|51) deg", out), out
    assert "wrote [mounting]" in out
    saved = cfg.load(path)
    assert saved.mounting.pitch_deg == pytest.approx(38.5, abs=0.1)
    assert saved.mounting.roll_deg == pytest.approx(2.0, abs=0.1)
    assert saved.camera.fps == 30.0  # the rest of the file is kept
    assert camera.calls == ["start", "stop", "close"] and imu.calls[-2:] == ["stop", "close"]


def test_calibrate_command_refuses_when_the_subject_moves(devices, tmp_path, capsys):
    from tui import cli

    moving = [tr.thigh_quaternion(0, 0, 0), tr.thigh_quaternion(12, 0, 0)]
    frames = [tr.render(tr.level(), q, mounting=TRUE_MOUNTING) for q in moving]
    devices([f[0] for f in frames], [f[1] for f in frames], moving)
    path = tmp_path / "walkcap.toml"
    path.write_text("[mounting]\npitch_deg = 35.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "0.3"]) == 1
    err = capsys.readouterr().err
    assert "moved" in err and "nothing written" in err and len(err.strip().splitlines()) == 1
    assert path.read_text() == "[mounting]\npitch_deg = 35.0\n"


def test_calibrate_dry_run_and_write_elsewhere(devices, tmp_path, capsys):
    from capture import config as cfg
    from tui import cli

    devices(*standing(count=2, sway_deg=0.0))
    assert cli.main(["calibrate", "--seconds", "0.2", "--dry-run"]) == 0
    assert "nothing written" in capsys.readouterr().out
    assert not (tmp_path / "walkcap.toml").exists()
    other = tmp_path / "rig.toml"
    assert cli.main(["calibrate", "--seconds", "0.2", "--write", str(other)]) == 0
    assert cfg.load(other).mounting.pitch_deg == pytest.approx(38.5, abs=0.1)
    capsys.readouterr()
    devices(*standing(count=2, sway_deg=0.0))
    assert cli.main(["calibrate", "--seconds", "0.2", "--dry-run", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] and data["written"] is None
    assert data["pitch_deg"] == pytest.approx(38.5, abs=0.1)


def test_calibrate_on_mock_devices_recovers_the_simulated_mounting(tmp_path, capsys):
    """End to end: the mock walker stands, the IMU emulator feels its thigh, the floor
    gives back the simulator's camera tilt; the config file gets [mounting]."""
    from capture import config as config_mod
    from tui import cli

    path = tmp_path / "walkcap.toml"
    path.write_text("[mounting]\npitch_deg = 20.0\n[simulator]\ncamera_tilt_deg = 32.0\n")
    assert cli.main(["--config", str(path), "calibrate", "--seconds", "1.5"]) == 0
    written = config_mod.load(path)
    assert abs(written.mounting.pitch_deg - 32.0) < 1.0
    assert abs(written.mounting.roll_deg) < 1.0
    assert written.simulator.camera_tilt_deg == 32.0  # the rest of the file is kept
    assert not written.simulator.stand  # standing is for the calibration only
