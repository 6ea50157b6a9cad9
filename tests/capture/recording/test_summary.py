"""`summary()`: one typed record behind `walkcap info` and `walkcap info --json`."""

import json

from capture.recording import RecordingSummary, summary
from capture.recording import topics as T
from capture.recording.reader import open_recording
from tests.recording_fixtures import T0, frame_time, write_trial
from tui import cli


def test_info_text_and_json_come_from_the_summary(tmp_path, capsys):
    path = tmp_path / "S01_indoor_t01.mcap"
    labels = [
        (T0, "LG", "operator"),
        (frame_time(30) + 1, "DS", "operator"),
        (frame_time(60) + 1, "LG", "undo:DS"),
    ]
    write_trial(path, labels)
    s = summary(open_recording(path))
    assert isinstance(s, RecordingSummary) and s.complete and not s.damaged
    assert s.labels == labels and s.in_reference == [True, False, False]
    assert s.undos == 1 and s.reference == [labels[0]]
    assert {t.topic: t.messages for t in s.topics}[T.CNN] == 90
    assert s.losses == {} and s.member.trial_name == "S01 indoor trial 1"

    assert cli.main(["info", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out) == [json.loads(json.dumps(s.to_json()))]
    assert cli.main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "labels      3 changes (1 undo(s) applied: what they took back is left out): LG" in text
    assert f"trial       S01 indoor trial 1; id {s.member.id}" in text
