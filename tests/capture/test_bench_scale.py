"""`walkcap bench --scale`: the synthesized trial is a trial of that length, the table says
the growth, and a bad --minutes is one line."""

from __future__ import annotations

import pytest

from capture.bench import scale
from capture.recording import topics as T
from capture.recording.reader import open_recording
from capture.recording.summary import summary


def test_a_synthesized_trial_has_every_stream_at_its_rate_and_nothing_lost(tmp_path):
    path = scale.synthesize(tmp_path / "B01_indoor_t01.mcap", 0.02)  # 1.2 s: 54 frames
    s = summary(open_recording(path))
    counts = {t.topic: t.messages for t in s.topics}
    assert counts[T.DEPTH] == counts[T.CNN] == counts[T.PREPROCESS] == 54
    assert counts[T.IMU] == 118 and counts[T.LABELS] == 1  # 100 Hz up to the last frame
    assert s.complete and all(not (x.gaps or x.late) for x in s.losses.values())
    assert s.processed_frames == 54 and s.labels[0][1] == "LG"


def test_the_table_gives_each_length_and_the_growth_from_the_shortest():
    runs = [
        scale.Run("info", 1, 2.0, 300.0, True),
        scale.Run("info", 4, 3.0, 330.0, True),
        scale.Run("export parquet", 1, 4.0, 350.0, True),
        scale.Run("export parquet", 4, 10.0, 350.0, False),
    ]
    lines = scale.table(runs)
    assert lines[0] == "| command | 1 min | 4 min | growth 1 -> 4 min (time, memory) |"
    assert lines[2] == "| info | 2.0 s, 300 MiB | 3.0 s, 330 MiB | 1.50x, 1.10x |"
    assert lines[3].endswith("10.0 s, 350 MiB (failed) | 2.50x, 1.00x |")


def test_several_runs_give_the_median_and_the_range():
    figures = [(3.0, 2.0, 100.0, True), (5.0, 2.2, 104.0, True), (4.0, 2.1, 101.0, True)]
    run = scale._run_of("replay", 4, figures)
    assert (run.seconds, run.cpu_s, run.peak_mib, run.ok) == (4.0, 2.1, 101.0, True)
    assert scale.table([run])[2] == (
        "| replay | 4.0 s (3.0-5.0), 2.1 s CPU, 101 MiB (100-104) | 1.00x, 1.00x |"
    )


@pytest.mark.slow
@pytest.mark.subprocess
def test_every_command_runs_on_a_short_trial(tmp_path):
    """Each command of the scale table, on a synthesized trial of a few seconds."""
    path = scale.synthesize(tmp_path / "B01_indoor_t01.mcap", 0.05)
    runs = scale.run([0.05], str(tmp_path), progress=lambda line: None, trials={0.05: path})
    assert [r.command for r in runs] == [name for name, _ in scale.COMMANDS]
    assert all(r.ok for r in runs), [r.command for r in runs if not r.ok]
    assert all(r.cpu_s > 0 and r.peak_mib > 0 for r in runs)


@pytest.mark.parametrize("minutes", ["", "1,x", "0,4"])
def test_bad_minutes_are_one_line(minutes, capsys):
    from tui import cli

    assert cli.main(["bench", "--scale", "--minutes", minutes]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--minutes" in err
