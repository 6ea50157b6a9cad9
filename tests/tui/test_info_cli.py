"""`walkcap info` and `walkcap recover` on good, cut-off and garbage files."""

from __future__ import annotations

import subprocess
import sys

import pytest

from capture.recording.journal import journal_path
from tests.recording_fixtures import write_recording
from tui import cli


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("info") / "S07_indoor_t03.mcap"
    write_recording(path, seconds=2.5)
    return path


def test_info_on_a_good_file(recording, capsys):
    assert cli.main(["info", str(recording)]) == 0
    out = capsys.readouterr().out
    assert "state       complete" in out
    lines = {line.split()[0]: line for line in out.splitlines() if line.startswith("    /")}
    assert lines["/camera/depth"].split()[1:4] == ["112", "45.0", "Hz"]
    assert lines["/imu"].split()[1:3] == ["247", "100.0"]
    assert "foxglove.PointCloud" in lines["/camera/cloud"]
    assert "gaps        /camera/depth none; /imu none" in out
    assert "labels      5 changes: LG US DS UR DR" in out
    assert "events      gap 1, marker 1" in out
    assert "subject=S07" in out and "model_hash=abc123" in out
    assert "camera_rays.npy" in out and "walkcap.toml" in out
    assert "2.5 s" in out or "2.4 s" in out


def test_info_on_a_cut_file_says_so_and_still_reads_it(recording, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recording.read_bytes()[: int(recording.stat().st_size * 0.7)])
    assert cli.main(["info", str(cut)]) == 0
    out = capsys.readouterr().out
    assert "unfinished (cut off" in out and f"walkcap recover {cut}" in out
    assert "/camera/depth" in out and "subject=S07" in out


@pytest.mark.parametrize("content", [b"", b"\x89PNG\r\n\x1a\n garbage " * 50], ids=["empty", "png"])
def test_info_on_garbage_is_one_clear_line(tmp_path, capsys, content):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    assert cli.main(["info", str(bad)]) == 1
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1 and "Traceback" not in out.err
    assert out.err.startswith(f"walkcap info: error: {bad} is ")
    assert ("empty" if not content else "not an MCAP recording") in out.err


@pytest.mark.subprocess
def test_info_on_a_missing_file_is_one_clear_line(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "tui.cli", "info", str(tmp_path / "x.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 1 and "Traceback" not in out.stderr
    assert out.stderr == f"walkcap info: error: {tmp_path / 'x.mcap'}: no such file\n"


def test_recover_cli_writes_an_indexed_copy_with_the_journal(recording, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recording.read_bytes()[: int(recording.stat().st_size * 0.5)])
    journal_path(cut).write_bytes(journal_path(recording).read_bytes())
    assert cli.main(["recover", str(cut)]) == 0
    out = capsys.readouterr().out
    rebuilt = tmp_path / "cut.recovered.mcap"
    assert f"wrote {rebuilt}" in out and "labels" in out and "cut off" in out
    assert cli.main(["info", str(rebuilt)]) == 0
    info = capsys.readouterr().out
    assert "state       complete" in info and "labels      5 changes" in info
    assert cli.main(["recover", str(cut)]) == 1  # never overwrites without --force
    assert "exists" in capsys.readouterr().err
    assert cli.main(["recover", str(cut), "--force"]) == 0
