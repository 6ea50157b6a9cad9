"""`walkcap imu`: decode captures, identify and stream a device, run the emulator."""

import json
import math
import subprocess
import sys

import pytest

from devices import xbus
from devices.imu.emulator import ImuEmulator
from tui import cli
from tui.commands.imu import DECODE_KEYS

pytestmark = pytest.mark.timeout(60)


def capture_bytes() -> bytes:
    every = {
        "packet_counter": 1,
        "sample_time_fine": 1000,
        "sample_time_coarse": 0,
        "quaternion": (1.0, 0.0, 0.0, 0.0),
        "euler": (1.0, 2.0, 3.0),
        "rotation_matrix": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
        "acceleration": (0.0, 0.0, 9.75),
        "free_acceleration": (0.0, 0.0, 0.0),
        "delta_v": (0.0, 0.0, 0.0975),
        "rate_of_turn": (0.5, 0.0, 0.0),
        "delta_q": (1.0, 0.0, 0.0, 0.0),
        "magnetic_field": (0.0, 0.4, -0.9),
        "temperature": 30.5,
        "baro_pressure": 101325,
        "status_word": 3,
    }
    full = xbus.build(xbus.MID.MTDATA2, xbus.encode_mtdata2(every))
    unknown = b"\x77\x70\x02ab"  # an unknown identifier, skipped by its size
    small = xbus.build(
        xbus.MID.MTDATA2,
        unknown
        + xbus.encode_mtdata2(
            {"packet_counter": 2, "quaternion": (0.0, 1.0, 0.0, 0.0)}, xbus.FP1632
        ),
    )
    bad = bytearray(full)
    bad[20] ^= 0xFF
    ack = xbus.build(xbus.MID.GOTO_CONFIG_ACK)
    return b"junk" + full + ack + bytes(bad) + small[:10] + small


def test_decode_json_lines_and_summary(tmp_path, capsys):
    path = tmp_path / "capture.bin"
    path.write_bytes(capture_bytes())
    assert cli.main(["imu", "decode", str(path), "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    first, second, summary = lines
    assert list(first) == list(DECODE_KEYS)  # every key, in the documented order
    assert first["quaternion"] == [1.0, 0.0, 0.0, 0.0]
    assert first["euler"] == [1.0, 2.0, 3.0]
    assert first["rotation_matrix"] == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    assert first["temperature"] == 30.5 and first["baro_pressure"] == 101325
    assert second == {"packet_counter": 2, "quaternion": [0.0, 1.0, 0.0, 0.0]}
    # resyncs: the corrupted and the cut message (no good one between); the junk before
    # the first message is a start mid-stream
    assert summary == {
        "summary": {
            "messages": 2,
            "checksum_errors": 2,
            "resyncs": 1,
            "unknown_ids": 1,
            "malformed": 0,
        }
    }


def test_decode_table(tmp_path, capsys):
    path = tmp_path / "capture.bin"
    path.write_bytes(capture_bytes())
    assert cli.main(["imu", "decode", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "quaternion" in out[0] and len(out) == 4
    assert out[1].split()[:2] == ["1", "1000"]
    assert "2 messages, 2 checksum errors" in out[-1]


def test_decode_json_writes_null_for_nan_and_infinity(tmp_path, capsys):
    values = {"packet_counter": 1, "acceleration": (math.nan, math.inf, 1.0)}
    values2 = {"packet_counter": 2, "temperature": -math.inf}
    path = tmp_path / "capture.bin"
    path.write_bytes(
        xbus.build(xbus.MID.MTDATA2, xbus.encode_mtdata2(values))
        + xbus.build(xbus.MID.MTDATA2, xbus.encode_mtdata2(values2, xbus.FLOAT64))
    )
    assert cli.main(["imu", "decode", str(path), "--json"]) == 0
    out = capsys.readouterr().out.splitlines()
    strict = [
        json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in JSON")) for line in out
    ]
    assert strict[0]["acceleration"] == [None, None, 1.0]
    assert strict[1]["temperature"] is None


def test_decode_keeps_going_after_a_payload_with_a_repeated_output(tmp_path, capsys):
    quaternion = xbus.encode_packet("quaternion", (1.0, 0.0, 0.0, 0.0), xbus.FP1632)
    counter = xbus.encode_packet("packet_counter", 5)
    path = tmp_path / "capture.bin"
    path.write_bytes(
        xbus.build(xbus.MID.MTDATA2, xbus.encode_packet("packet_counter", 4))
        + xbus.build(xbus.MID.MTDATA2, counter + quaternion + quaternion)
        + xbus.build(xbus.MID.MTDATA2, xbus.encode_packet("packet_counter", 6))
    )
    assert cli.main(["imu", "decode", str(path), "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [obj.get("packet_counter") for obj in lines[:3]] == [4, 5, 6]
    assert lines[1]["quaternion"] == [1.0, 0.0, 0.0, 0.0]
    assert lines[3]["summary"]["messages"] == 3


def test_fuzz_command_reports_streams_and_no_exceptions(capsys):
    assert cli.main(["imu", "fuzz", "--streams", "2000", "--seed", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["streams"] == 2000 and report["exceptions"] == 0
    assert sum(report["by_kind"].values()) == 2000
    assert 0 <= report["lost_next"] < 20 and report["malformed"] > 0


def test_fuzz_with_no_streams_is_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["imu", "fuzz", "--streams", "0"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--streams" in err[0]


def test_decode_missing_file_is_one_line(capsys):
    assert cli.main(["imu", "decode", "nowhere.bin"]) == 1
    err = capsys.readouterr().err
    assert "nowhere.bin" in err and len(err.strip().splitlines()) == 1


@pytest.mark.realtime
def test_info_against_the_emulator(capsys):
    with ImuEmulator() as emulator:
        assert cli.main(["imu", "info", emulator.port]) == 0
    out = capsys.readouterr().out
    assert "03881234" in out and "MTi-3-8A7G6" in out and "1.8.2" in out
    assert "quaternion" in out and "every packet" in out
    assert "MTi-1 series, AHRS" in out
    assert "link budget   100 messages/s x 73 bytes = 73.0 kbit/s of 115.2 kbit/s" in out


@pytest.mark.realtime
def test_info_of_an_imu_only_model_says_leveling_needs_orientation(capsys):
    with ImuEmulator(model="MTi-1") as emulator:
        assert cli.main(["imu", "info", emulator.port]) == 0
    out = capsys.readouterr().out
    assert "MTi-1 series, IMU" in out and "quaternion" not in out
    assert "leveling needs a VRU or AHRS" in out


@pytest.mark.realtime
def test_set_baud_then_the_device_answers_at_the_new_rate(capsys):
    with ImuEmulator(model="MTi-630") as emulator:
        assert cli.main(["imu", "set-baud", emulator.port, "460800"]) == 0
        assert emulator.baudrate == 460800
        assert "115200 -> 460800 baud" in capsys.readouterr().out
        assert cli.main(["imu", "info", emulator.port, "--baudrate", "460800"]) == 0
        assert "at 460800 baud" in capsys.readouterr().out
        with pytest.raises(SystemExit) as usage:  # argparse's usage error: status 2
            cli.main(["imu", "set-baud", emulator.port, "1234"])
        assert usage.value.code == 2 and "one of the Xsens baud rates" in capsys.readouterr().err


def test_info_on_a_missing_port_is_one_line(capsys, tmp_path):
    assert cli.main(["imu", "info", str(tmp_path / "ttyNone")]) == 1
    assert "cannot open IMU port" in capsys.readouterr().err


def test_stream_mock_with_a_raw_capture_that_decodes(tmp_path, capsys):
    raw = tmp_path / "raw.bin"
    assert (
        cli.main(
            ["imu", "stream", "mock", "--seconds", "1.2", "--interval", "0.4", "--raw", str(raw)]
        )
        == 0
    )
    out = capsys.readouterr().out.splitlines()
    assert "MTi-3-8A7G6" in out[0]
    assert any("Hz" in line and "rpy" in line for line in out[1:])
    assert cli.main(["imu", "decode", str(raw), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])["summary"]
    assert summary["messages"] > 50 and summary["checksum_errors"] == 0


@pytest.mark.realtime
@pytest.mark.slow
@pytest.mark.subprocess
def test_emulate_prints_its_port_and_list_runs():
    out = subprocess.run(
        [sys.executable, "-m", "tui.cli", "imu", "emulate", "--seconds", "0.3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0].endswith("ttyIMU")
    assert "walkcap imu stream" in out.stderr
    listed = subprocess.run(
        [sys.executable, "-m", "tui.cli", "imu", "list"], capture_output=True, text=True, timeout=60
    )
    assert listed.returncode == 0 and listed.stdout.strip()


def test_a_verb_is_required(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["imu"])
    assert e.value.code == 2
