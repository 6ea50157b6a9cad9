"""`with open_recording(path) as rec:` and `rec.messages(topics, start=, end=)`: a window of
time read through the chunk index, only the chunks that overlap it decompressed."""

from __future__ import annotations

import pytest
from mcap.reader import make_reader

from capture.recording import messages as messages_mod
from capture.recording import open_recording
from capture.recording import topics as T
from capture.recording.reader import RecordedMessage
from tests.recording_fixtures import write_recording

SECONDS = 3.0
real_chunk_messages = messages_mod.chunk_messages


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("window") / "trial.mcap"
    write_recording(path, seconds=SECONDS, chunk_interval_s=0.25)  # about a dozen chunks
    return path


@pytest.fixture
def decompressed(monkeypatch):
    """The chunk offsets the reader decompresses, in order."""
    seen: list[int] = []
    real = messages_mod.chunk_messages

    def counted(f, offset, length, wanted):
        seen.append(offset)
        return real(f, offset, length, wanted)

    monkeypatch.setattr(messages_mod, "chunk_messages", counted)
    return seen


def _chunks(path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary().chunk_indexes


def test_a_window_reads_only_the_chunks_that_overlap_it(recording, decompressed):
    everything = list(open_recording(recording).messages(T.IMU))
    t = [m.log_time_ns for m in everything]
    t0, t1 = t[len(t) // 3], t[len(t) // 2]
    chunks = _chunks(recording)
    assert len(chunks) >= 8
    decompressed.clear()
    with open_recording(recording) as rec:
        window = list(rec.messages("/imu", start=t0, end=t1))
    assert [m.log_time_ns for m in window] == [x for x in t if t0 <= x < t1]
    assert all(isinstance(m, RecordedMessage) and m.topic == T.IMU for m in window)
    assert [m.data for m in window] == [m.data for m in everything if t0 <= m.log_time_ns < t1]
    # the chunks that hold an IMU message of the window, every chunk opened to see
    with open(recording, "rb") as f:
        summary = make_reader(f).get_summary()
        imu = {cid for cid, c in summary.channels.items() if c.topic == T.IMU}
        holding = {
            c.chunk_start_offset
            for c in chunks
            if any(
                t0 <= log_time < t1
                for _, _, log_time, _, _ in real_chunk_messages(
                    f, c.chunk_start_offset, c.chunk_length, imu
                )
            )
        }
    assert set(decompressed) == holding
    assert len(decompressed) <= len(chunks) / 3


def test_a_list_of_topics_in_a_window_comes_in_file_order(recording, decompressed):
    with open_recording(recording) as rec:
        start, end = rec.start_ns, rec.end_ns
        mid = start + (end - start) // 2
        got = list(rec.messages([T.IMU, T.CNN], start=mid, end=end + 1))
        assert {m.topic for m in got} == {T.IMU, T.CNN}
        assert all(mid <= m.log_time_ns <= end for m in got)
        whole = [m for m in rec.messages([T.IMU, T.CNN]) if m.log_time_ns >= mid]
    assert [(m.topic, m.log_time_ns) for m in got] == [(m.topic, m.log_time_ns) for m in whole]


def test_reads_in_a_with_block_share_one_open_file_and_one_index(recording, monkeypatch):
    rec = open_recording(recording)
    read = []
    monkeypatch.setattr(messages_mod, "read_summary", lambda f: read.append(f) or None)
    with rec:
        a = rec.messages(T.IMU, end=rec.start_ns + 10**9)
        b = rec.messages(T.CNN, end=rec.start_ns + 10**9)
        first = [next(a), next(b), next(a)]  # interleaved generators on the one handle
        assert [m.topic for m in first] == [T.IMU, T.CNN, T.IMU]
        assert len(list(a)) > 0 and len(list(b)) > 0
    assert read == []  # the index read when opened serves every call
    assert rec._file is None  # closed on leaving the block
    assert len(list(rec.messages(T.CNN, end=rec.start_ns + 10**9))) > 0  # reopens


def test_an_unfinished_file_is_windowed_too(recording, tmp_path):
    chunks = sorted(_chunks(recording), key=lambda c: c.chunk_start_offset)
    cut = tmp_path / "cut.mcap"
    keep = chunks[5].chunk_start_offset + chunks[5].chunk_length + 100
    cut.write_bytes(recording.read_bytes()[:keep])
    rec = open_recording(cut)
    assert not rec.complete
    t = [m.log_time_ns for m in rec.messages(T.IMU)]
    assert len(t) > 100
    t0, t1 = t[len(t) // 4], t[len(t) // 2]
    with open_recording(cut) as rec:
        got = [m.log_time_ns for m in rec.messages(T.IMU, start=t0, end=t1)]
    assert got == [x for x in t if t0 <= x < t1]
