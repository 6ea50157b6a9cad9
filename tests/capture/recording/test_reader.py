"""The Python reader: trials as per-frame arrays, depth frames, finished and unfinished files."""

from __future__ import annotations

import numpy as np
import pytest

from capture.corpus.trials import read_trial
from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.labels import labels_at
from capture.recording.reader import depth_frames, open_recording
from capture.recording.writer import Recorder
from devices.frames import MODES
from tests.recording_fixtures import (
    ATTACHMENTS,
    FPS,
    T0,
    frame_at,
    frame_time,
    label_schedule,
    probabilities,
    truth_mode,
    write_recording,
)


def test_read_trial_gives_per_frame_arrays_with_the_label_in_force(recording):
    trial = read_trial(recording)
    n = int(2.0 * FPS)
    np.testing.assert_array_equal(trial.frames.index, np.arange(n))
    np.testing.assert_array_equal(trial.frames.time_ns, [frame_time(i) for i in range(n)])
    np.testing.assert_allclose(trial.frames.probabilities, [probabilities(i) for i in range(n)])
    assert trial.frames.probabilities.shape == (n, len(MODES))
    np.testing.assert_array_equal(trial.frames.cnn_decision, trial.frames.probabilities.argmax(1))
    # fused decisions are filed under the frame they refer to (one earlier), votes two earlier
    expected = [MODES.index(truth_mode(i)) if 1 <= i <= n - 2 else -1 for i in range(n)]
    np.testing.assert_array_equal(trial.frames.decision, expected)
    assert trial.frames.voted[0] == -1 and (trial.frames.voted[n - 2 :] == -1).all()
    np.testing.assert_array_equal(
        trial.frames.voted[1 : n - 2], [MODES.index(truth_mode(i)) for i in range(1, n - 2)]
    )
    np.testing.assert_array_equal(trial.truth, [MODES.index(truth_mode(i)) for i in range(n)])
    changes = label_schedule(2.0)
    assert trial.label_changes == changes
    for i in range(n):  # the last change at or before the frame's time
        before = [mode for t, mode, _ in changes if t <= frame_time(i)]
        assert trial.frames.labels[i] == (MODES.index(before[-1]) if before else -1)
    assert trial.meta.session.subject == "S07"


def test_labels_at_handles_undo_to_nothing_and_same_time_changes():
    changes = [
        (10, "LG", "operator"),
        (20, "US", "operator"),
        (20, "DS", "operator"),
        (30, "", "undo:DS"),
    ]
    np.testing.assert_array_equal(
        labels_at(np.array([5, 10, 19, 20, 29, 30, 99]), changes), [-1, 0, 0, 2, 2, -1, -1]
    )


def test_without_truth_the_trial_says_so(tmp_path):
    path = tmp_path / "real.mcap"
    with Recorder(path, metadata={}) as rec:
        rec.write_inference(0, T0, T0, probabilities(0), {})
        rec.write_label(T0 - 1, "UR", "operator")
    trial = read_trial(path)
    assert trial.truth is None and trial.frames.labels.tolist() == [MODES.index("UR")]
    assert trial.frames.decision.tolist() == [-1]


def test_messages_decode_into_numpy_and_dicts(recording):
    rec = open_recording(recording)
    assert rec.complete and rec.topics[T.DEPTH].count == 90
    assert rec.topics[T.CLOUD].schema_name == "foxglove.PointCloud"
    cloud = rec.read(T.CLOUD)[0]
    assert cloud.data.shape == (300, 3) and cloud.data.dtype == np.float32
    assert cloud.sequence == 0 and cloud.publish_time_ns == frame_time(0)
    tf = rec.read(T.TF)[0].data
    np.testing.assert_allclose(tf, [np.cos(0.1), 0, np.sin(0.1), 0])
    depth = rec.read(T.DEPTH)[0].data
    assert depth.dtype == np.uint16 and depth.shape == (171, 224)
    raw = next(rec.messages(T.DEPTH, raw=True))
    assert raw.data.encoding == "16UC1"
    imu = rec.read(T.IMU)
    assert all(isinstance(m.data, dict) for m in imu)
    assert [m.data["packet_counter"] for m in imu[:3]] == [0, 1, 2]
    assert rec.duration_s == pytest.approx((frame_time(89) - T0) * 1e-9, abs=0.05)


def test_log_times_from_the_index_match_a_full_read(recording):
    rec = open_recording(recording)
    times = rec.log_times()
    for topic in (T.DEPTH, T.IMU, T.LABELS):
        np.testing.assert_array_equal(
            times[topic], sorted(m.log_time_ns for m in rec.messages(topic))
        )


def test_an_unfinished_file_reads_up_to_its_cut(recording, tmp_path):
    from mcap.reader import make_reader

    with open(recording, "rb") as f:
        first = make_reader(f).get_summary().chunk_indexes[0]
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: first.chunk_start_offset + first.chunk_length + 5000])
    rec = open_recording(cut)
    assert not rec.complete and "cut off" in rec.reason
    assert rec.metadata["session"]["subject"] == "S07"
    assert 0 < rec.topics[T.DEPTH].count < 90
    frames = list(depth_frames(cut))
    assert [f.index for f in frames] == list(range(rec.topics[T.DEPTH].count))
    original = frame_at(3)
    valid = original.confidence > 0
    error = np.linalg.norm(frames[3].xyz - original.xyz, axis=-1)[valid]
    assert error.max() <= 0.0005 + 1e-6
    assert frames[3].truth["mode"] == truth_mode(3)
    trial = read_trial(cut)
    assert len(trial.frames.index) > 0


def test_a_finished_file_is_read_one_chunk_at_a_time(tmp_path):
    """Messages of the first chunk come before a later chunk is even opened (a long
    recording is never all in memory): damage in the last chunk shows only once reached."""
    from mcap.reader import make_reader

    path = tmp_path / "long.mcap"
    write_recording(path, seconds=2.0, chunk_interval_s=0.25)
    with open(path, "rb") as f:
        chunks = sorted(
            make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
        )
    assert len(chunks) >= 4
    data = bytearray(path.read_bytes())
    last = chunks[-1]
    middle = last.chunk_start_offset + last.chunk_length // 2
    data[middle : middle + 64] = bytes(64)  # zeros inside the last chunk's compressed data
    path.write_bytes(bytes(data))
    frames = depth_frames(path)
    first = next(frames)
    assert first.index == 0 and first.truth["mode"] == truth_mode(0)
    with pytest.raises(CaptureError, match="damaged"):
        list(frames)
    # chunks without a wanted topic are skipped, not opened: the labels come out whole
    rec = open_recording(path)
    assert [m.data["mode"] for m in rec.messages(T.LABELS)] == [
        mode for _, mode, _ in label_schedule(2.0)
    ]


def test_frames_after_the_truth_stops_come_out_as_they_are_read(tmp_path, monkeypatch):
    """A frame waits for its truth only so long: where the truth stops, frames still
    stream (damage at the end of the file shows after them, not before)."""
    from mcap.reader import make_reader

    import capture.recording.reader as reader

    monkeypatch.setattr(reader, "_TRUTH_WAIT_FRAMES", 4)
    path = tmp_path / "half.mcap"
    n = int(2 * FPS)
    with Recorder(path, metadata={}, attachments=dict(ATTACHMENTS), chunk_interval_s=0.25) as rec:
        for i in range(n):
            frame = frame_at(i)
            rec.write_frame(frame)
            if i < 8:
                rec.write_truth(i, frame.device_time_ns, frame.truth)
    with open(path, "rb") as f:
        last = max(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = bytearray(path.read_bytes())
    middle = last.chunk_start_offset + last.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    frames = []
    with pytest.raises(CaptureError, match="damaged"):
        for frame in depth_frames(path):
            frames.append(frame)
    assert [f.index for f in frames] == list(range(len(frames))) and len(frames) > 16
    assert all(f.truth["mode"] == truth_mode(f.index) for f in frames[:8])
    assert all(f.truth is None for f in frames[8:])


def test_missing_and_foreign_files_are_one_line_errors(tmp_path):
    with pytest.raises(CaptureError, match="no such file"):
        open_recording(tmp_path / "nope.mcap")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(CaptureError, match="not an MCAP recording"):
        open_recording(text)


def test_two_references_live_keys_and_offline_terrain_labels(tmp_path):
    """The live keys are the locomotion reference; labels made offline in replay --tui
    (source "correction") over them are the terrain reference; with neither the
    simulator's truth nor offline labels there is no terrain reference."""
    from tests.recording_fixtures import T0, frame_time, write_trial

    keys = [(T0, "LG", "operator"), (frame_time(40), "US", "operator")]
    live = tmp_path / "live.mcap"
    write_trial(live, keys, frames=80)
    trial = read_trial(live)
    assert trial.frames.terrain is None and trial.frames.terrain_source is None
    assert list(trial.frames.locomotion[[0, 39, 40, 79]]) == [0, 0, 1, 1]
    labelled = tmp_path / "labelled.mcap"
    write_trial(labelled, [*keys, (frame_time(25), "US", "correction")], frames=80)
    trial = read_trial(labelled)
    assert trial.frames.terrain_source == "offline labels"
    assert list(trial.frames.terrain[[0, 24, 25, 79]]) == [0, 0, 1, 1]  # the image shows US early
    assert list(trial.frames.locomotion[[0, 39, 40, 79]]) == [0, 0, 1, 1]  # the keys unchanged


def test_export_names_both_references(tmp_path):
    from capture.corpus import export
    from tests.recording_fixtures import T0, frame_time, write_trial

    keys = [(T0, "LG", "operator"), (frame_time(40), "US", "operator")]
    path = tmp_path / "labelled.mcap"
    write_trial(path, [*keys, (frame_time(25), "US", "correction")], frames=80)
    frames = export.tables(path)["frames"]
    assert list(frames["terrain"][[0, 24, 25, 79]]) == ["LG", "LG", "US", "US"]
    assert list(frames["locomotion"][[0, 39, 40, 79]]) == ["LG", "LG", "US", "US"]
    live = tmp_path / "live.mcap"
    write_trial(live, keys, frames=80)
    assert set(export.tables(live)["frames"]["terrain"]) == {""}  # labelled offline: none
