"""`summary()`: one typed record behind `walkcap info` and `walkcap info --json`."""

import json

from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.reader import open_recording
from capture.recording.summary import RecordingSummary, summary
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


# ---- one pass, bounded memory -----------------------------------------------------------


def test_info_reads_each_chunk_once_and_never_every_message_time(tmp_path, monkeypatch):
    """The counts come from the summary; damage, gaps, labels and flags from one pass that
    opens each chunk once: the per-topic readers (every message's times, every sensor
    item) are never asked."""
    from mcap.reader import make_reader

    from capture.recording import _mcap, messages
    from capture.recording.reader import Recording
    from tests.recording_fixtures import write_recording

    path = tmp_path / "S01_indoor_t01.mcap"
    write_recording(path, seconds=2.0, chunk_interval_s=0.25)
    with open(path, "rb") as f:
        chunks = len(make_reader(f).get_summary().chunk_indexes)
    rec = open_recording(path)
    whole = {t: len(rec.read(t)) for t in rec.topics}
    opened = []
    real = _mcap._decompress
    monkeypatch.setattr(_mcap, "_decompress", lambda *a: opened.append(1) or real(*a))

    def refused(*args, **kwargs):
        raise AssertionError("info read the file message by message")

    monkeypatch.setattr(messages, "iter_raw", refused)
    monkeypatch.setattr(Recording, "log_times", refused)
    monkeypatch.setattr(Recording, "sequences", refused)
    s = summary(rec)
    assert len(opened) == chunks > 4
    assert {t.topic: t.messages for t in s.topics} == whole
    assert s.losses is not None and s.frame_flags == {"no orientation": 1}
    assert s.events == {"gap": 1, "marker": 1} and s.markers[0][1] == "stairs start"


def test_a_cut_file_is_described_by_the_scan_as_a_reading_of_it(tmp_path):
    """No summary: the fallback scan's counts, labels and gaps are what a full read finds."""
    from capture.recording.gaps import recording_loss
    from tests.recording_fixtures import write_recording

    path = tmp_path / "S01_indoor_t01.mcap"
    write_recording(path, seconds=3.0, chunk_interval_s=0.25)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.6)])
    rec = open_recording(cut)
    assert not rec.complete
    s = summary(rec)
    read = {t: len(rec.read(t)) for t in rec.topics}
    assert {t.topic: t.messages for t in s.topics} == read
    assert 0 < read[T.DEPTH] < open_recording(path).topics[T.DEPTH].count
    assert s.labels == L.in_time_order(
        [L.change_from_message(m.data) for m in rec.messages([T.LABELS])]
    )
    assert s.losses == recording_loss(rec)
    whole = summary(open_recording(path))
    rates = {t.topic: t.rate_hz for t in whole.topics}
    for t in s.topics:
        if t.rate_hz is not None:
            assert abs(t.rate_hz - rates[t.topic]) < 0.05 * rates[t.topic]


def test_the_scan_gives_back_the_pages_it_has_read(tmp_path, monkeypatch):
    """A mapped file's pages count as the reader's memory: the scan drops them behind it,
    so what it holds does not grow with the file."""
    import mmap

    from capture.recording import _mcap, checking
    from tests.recording_fixtures import write_recording

    path = tmp_path / "S01_indoor_t01.mcap"
    write_recording(path, seconds=2.0, chunk_interval_s=0.25)
    given_back = []

    class Mapped(mmap.mmap):
        def madvise(self, option, start=0, length=None):
            given_back.append((start, length))
            return super().madvise(option, start, length)

    monkeypatch.setattr(_mcap, "_RELEASE_BYTES", mmap.PAGESIZE)
    monkeypatch.setattr(
        _mcap, "file_bytes", lambda f: Mapped(f.fileno(), 0, access=mmap.ACCESS_READ)
    )
    result = checking.check(path)
    assert result.complete and len(given_back) > 3
    starts = [s for s, _ in given_back]
    assert starts == sorted(starts) and starts[0] == 0
    held = [b[0] - (a[0] + a[1]) for a, b in zip(given_back, given_back[1:], strict=False)]
    assert held == [0] * len(held)  # each release starts where the one before ended
    assert given_back[-1][0] + given_back[-1][1] > path.stat().st_size // 2


def test_recorded_loss_counts_in_receive_order_with_a_bounded_window():
    """Items a little out of receive order are counted as the sorted stream; the counter
    holds no more than its window whatever the stream's length."""
    import random

    from capture.recording import gaps

    period = 0.01
    items = []
    for k in range(5000):
        if k in (1000, 1001, 3000):
            continue
        host = int(k * period * 1e9) + (300_000_000 if k >= 4000 else 0)
        items.append((k % (1 << 16), int(k * period * 1e9), host))
    shuffled = items[:]
    for i in range(0, len(shuffled) - 8, 8):  # neighbours swapped, as a busy writer might
        j = i + random.Random(i).randrange(8)
        shuffled[i], shuffled[j] = shuffled[j], shuffled[i]
    counter = gaps.RecordedLoss("imu", period)
    most = 0
    for seq, dev, host in shuffled:
        counter.add(seq, dev, host)
        most = max(most, len(counter._heap))
    expected = gaps.stream_loss(sorted(items, key=lambda x: x[2]), period, 1 << 16, False)
    assert counter.loss() == expected
    assert [g.missing for g in expected.gaps] == [2, 1] and len(expected.late) == 1
    assert most <= gaps._REORDER + 1
