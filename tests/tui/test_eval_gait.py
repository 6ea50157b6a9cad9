"""`walkcap eval gait` on what it cannot judge: one clear line, no traceback."""

from __future__ import annotations

import pytest

from tests.recording_fixtures import write_recording
from tui import cli


def test_recordings_without_the_simulators_gait_are_left_out_and_said(tmp_path, capsys):
    path = tmp_path / "plain.mcap"
    write_recording(path, seconds=0.5)  # every topic but the gait events
    assert cli.main(["eval", "gait", str(path)]) == 1
    err = capsys.readouterr().err
    assert "left out: " in err and "no /sim/gait" in err
    assert "no recording with the simulator's gait events" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("argv", [["--tolerance-ms", "0"], ["--tolerance-ms", "x"]])
def test_a_bad_tolerance_is_a_usage_error(tmp_path, capsys, argv):
    with pytest.raises(SystemExit) as e:
        cli.main(["eval", "gait", str(tmp_path), *argv])
    assert e.value.code == 2
    assert "MS" in capsys.readouterr().err
