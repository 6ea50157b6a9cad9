"""The trials panel with a long session and a full folder: what it shows, and what it reads."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

from tui.app import TrialRecord
from tui.live_screen import LiveScreen


def test_the_panel_shows_the_last_trials_and_the_count_whatever_their_number():
    shown = []
    screen = SimpleNamespace(
        app=SimpleNamespace(
            trials=[TrialRecord(k, f"/data/S01_indoor_t{k:03d}.mcap") for k in range(500)]
        ),
        _trials_shown=None,
        query_one=lambda *a: SimpleNamespace(update=shown.append),
    )
    LiveScreen._show_trials(screen)
    lines = str(shown[-1]).splitlines()
    assert lines[0] == "… 497 earlier (all are listed on quit)"
    assert len(lines) == 4 and "t499" in lines[-1] and "t497" in lines[1]


def test_the_next_trial_number_in_a_folder_of_500_opens_no_recording(tmp_path, monkeypatch):
    """Naming a new trial reads file names only: a folder of hundreds costs no file read."""
    from capture.recording import naming
    from tests.recording_fixtures import write_trial

    seed = tmp_path / "seed.mcap"
    write_trial(seed, [], frames=3)
    folder = tmp_path / "recordings"
    folder.mkdir()
    for k in range(1, 501):
        shutil.copy(seed, folder / f"S01_indoor_t{k:02d}_20261204-1200{k:02d}.mcap")

    def refused(*args):
        raise AssertionError("a recording was opened to number a trial")

    monkeypatch.setattr(naming, "open_recording", refused)
    trial, supersedes, notice = naming.trial_conflict(folder, "S01", "indoor", 7, "next")
    assert trial == 501 and supersedes == [] and "trial 7 exists" in notice
