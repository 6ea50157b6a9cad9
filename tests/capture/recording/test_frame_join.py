"""The per-frame join holds only the frames still open, and its table is the same whatever
the window and however late a frame's message comes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.frames import FrameJoin
from capture.recording.reader import open_recording
from tests.recording_fixtures import T0, write_recording, write_trial


def _table(messages, join: FrameJoin, has_truth: bool):
    for m in messages:
        join.add(m)
    return join.table([(T0, "LG", "operator")], has_truth=has_truth)


def _same(a, b) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


@pytest.fixture(scope="module")
def every_topic(tmp_path_factory):
    path = tmp_path_factory.mktemp("join") / "trial.mcap"
    write_recording(path, seconds=2.0)
    rec = open_recording(path)
    topics = [t for t in FrameJoin.TOPICS if t in rec.topics]
    assert {T.CNN, T.FUSED, T.PREPROCESS, T.TF, T.TRUTH} <= set(topics)
    return list(rec.messages(topics)), T.TRUTH in rec.topics


def test_a_window_of_no_frames_gives_the_table_of_a_wide_one(every_topic):
    messages, truth = every_topic
    wide = _table(messages, FrameJoin(lateness=10**9), truth)
    narrow_join = FrameJoin(lateness=0)
    narrow = _table(messages, narrow_join, truth)
    assert len(wide) > 50 and narrow_join.held_peak < wide.index.size
    _same(narrow, wide)
    assert (wide.decision >= 0).any() and (wide.voted >= 0).any() and wide.classified.any()


def test_messages_far_behind_their_frame_are_laid_over_its_row(every_topic):
    messages, truth = every_topic
    in_order = _table(messages, FrameJoin(), truth)
    # every fused message and every orientation comes at the end, long after its frame
    late = {T.FUSED, T.TF}
    delayed = [m for m in messages if m.topic not in late] + [
        m for m in messages if m.topic in late
    ]
    join = FrameJoin(lateness=2)
    _same(_table(delayed, join, truth), in_order)
    # and a frame whose own CNN output and preprocessing come late still gets its row
    k = int(in_order.index[5])
    own = [m for m in messages if m.topic in (T.CNN, T.PREPROCESS) and m.data["frame_index"] == k]
    rest = [m for m in messages if m not in own]
    _same(_table(rest + own, FrameJoin(lateness=2), truth), in_order)


def test_a_long_trial_holds_a_window_of_frames_not_the_trial(tmp_path):
    path = tmp_path / "long.mcap"
    write_trial(path, [(T0, "LG", "operator")], frames=4000)
    rec = open_recording(path)
    join = FrameJoin()
    table = _table(rec.messages([T.CNN, T.FUSED]), join, False)
    assert len(table) == 4000 and list(table.index) == list(range(4000))
    assert join.held_peak <= FrameJoin.LATENESS + 2 * FrameJoin._BATCH
    assert not join.late and not join.open
    assert (table.labels == L.mode_index("LG")).all()


def test_a_frames_fusion_cues_come_from_its_features_and_a_foreign_field_is_unknown():
    """geometry and ground_ahead, as the fusions take them, from each frame's recorded
    terrain features; a field of another type (a foreign file's) is unknown (-1), not a
    failure of every reader of the table."""
    from types import SimpleNamespace

    from devices.frames import MODES

    def cnn(k):
        data = {"frame_index": k, "time_ns": T0 + k, "probabilities": [0.2] * 5}
        return SimpleNamespace(topic=T.CNN, data=data | {"decision": "LG"}, log_time_ns=T0 + k)

    def features(k, **fields):
        data = {"frame_index": k, "time_ns": T0 + k, **fields}
        return SimpleNamespace(topic=T.FEATURES, data=data, log_time_ns=T0 + k)

    messages = [
        cnn(0),
        features(0, kind="stairs", direction="up", ahead_slope_deg=8.0),
        cnn(1),
        features(1, kind=["stairs"], direction="up", ahead_slope_deg="8"),
        cnn(2),
    ]
    for keep in (True, False):
        table = _table(messages, FrameJoin(keep_features=keep), False)
        assert table.geometry.tolist() == [MODES.index("US"), -1, -1]
        assert table.ground_ahead.tolist() == [MODES.index("UR"), -1, -1]
        assert (table.features[0] != {}) == keep and table.features[2] == {}
