"""Copies of a recording (capture.recording.copy): every original message as it was, plus
what is added; the copy is a new recording derived from its source."""

from collections import Counter

import pytest

from capture.errors import CaptureError
from capture.recording import lineage
from capture.recording import topics as T
from capture.recording.copy import copy_recording
from capture.recording.messages import iter_raw
from capture.recording.reader import open_recording
from capture.recording.recover import recover
from tests.recording_fixtures import ATTACHMENTS, T0, write_recording


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("copy") / "S07_indoor_t03.mcap"
    write_recording(path, seconds=1.0)
    return path


def messages(path) -> Counter:
    """Every message as stored: topic, times, sequence and bytes."""
    rec = open_recording(path)
    return Counter(
        (c.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
        for _, c, m in iter_raw(rec.path, rec.complete, None)
    )


def test_a_copy_keeps_every_message_and_adds_the_new_ones(recording, tmp_path):
    label = T.label_json(T0 + 5, "US", "correction")
    marker = T.event_json({"time_ns": T0 + 9, "device": "operator", "kind": "marker"})
    out = copy_recording(
        recording,
        tmp_path / "copy.mcap",
        kind=lineage.CORRECTED,
        how="1 label correction(s)",
        labels=[label],
        events=[marker],
        metadata=[("corrections", {"source": recording.name, "labels": [[T0 + 5, "US"]]})],
    )
    added = messages(out) - messages(recording)
    assert messages(recording) - messages(out) == Counter()  # nothing lost or changed
    assert added == Counter(
        {
            (T.LABELS, T0 + 5, T0 + 5, 0, T.encode_json(label)): 1,
            (T.EVENTS, T0 + 9, T0 + 9, 0, T.encode_json(marker)): 1,
        }
    )
    a, b = open_recording(recording), open_recording(out)
    assert b.attachments == a.attachments and set(ATTACHMENTS) <= set(b.attachments)
    assert b.metadata["session"] == a.metadata["session"]
    assert b.metadata["corrections"]["labels"] == [[T0 + 5, "US"]]
    assert b.id != a.id and b.metadata["recording"]["id"] == b.id
    member = lineage.describe(b)
    assert member.kind == lineage.CORRECTED and member.source_id == a.id
    assert member.source_name == recording.name and member.how == "1 label correction(s)"


def test_a_copy_is_a_new_file(recording, tmp_path):
    with pytest.raises(CaptureError, match="new file"):
        copy_recording(recording, recording, kind=lineage.CORRECTED, how="")
    out = copy_recording(recording, tmp_path / "c.mcap", kind=lineage.CORRECTED, how="")
    with pytest.raises(CaptureError, match="never overwritten"):
        copy_recording(recording, out, kind=lineage.CORRECTED, how="")


def test_recover_copies_every_message_through_the_same_copy(recording, tmp_path):
    report = recover(recording, tmp_path / "r.mcap")
    assert messages(report.output) == messages(recording)
    member = lineage.describe(open_recording(report.output))
    assert member.kind == lineage.RECOVERED and member.source_id == open_recording(recording).id
