"""Export writes a trial's tables in pieces (Parquet row groups, CSV blocks, one MATLAB
struct at a time), and what it writes is what writing each table whole gives."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from capture.corpus import export
from tests.recording_fixtures import write_recording


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "S07_indoor_t03.mcap"
    write_recording(path, seconds=2.0)
    return export.tables(path)


def test_parquet_in_row_groups_reads_back_as_the_whole_table(tables, tmp_path, monkeypatch):
    import pyarrow.parquet as pq

    monkeypatch.setattr(export, "ROW_GROUP", 16)
    export.write(tables, tmp_path / "parts", "parquet")
    for name, df in tables.items():
        whole = tmp_path / f"{name}.whole.parquet"
        df.to_parquet(whole, index=False)
        part = tmp_path / "parts" / f"{name}.parquet"
        groups = pq.ParquetFile(part).num_row_groups
        assert groups == max(1, -(-len(df) // 16))
        pd.testing.assert_frame_equal(pd.read_parquet(part), pd.read_parquet(whole))
    assert pq.ParquetFile(tmp_path / "parts" / "imu.parquet").num_row_groups > 4


def test_csv_in_blocks_is_the_whole_table(tables, tmp_path, monkeypatch):
    monkeypatch.setattr(export, "ROW_GROUP", 16)
    export.write(tables, tmp_path, "csv")
    for name, df in tables.items():
        assert (tmp_path / f"{name}.csv").read_text() == df.to_csv(index=False)


def test_mat_written_table_by_table_is_the_one_savemat_writes(tables, tmp_path):
    from scipy.io import loadmat, savemat

    export.write(tables, tmp_path / "parts", "mat")
    whole = tmp_path / "whole.mat"
    savemat(whole, {n: export._mat_struct(df) for n, df in tables.items()}, oned_as="column")
    got, want = loadmat(tmp_path / "parts" / "walkcap.mat"), loadmat(whole)
    names = [k for k in want if not k.startswith("__")]
    assert names == list(tables) and [k for k in got if not k.startswith("__")] == names
    for name in names:
        a, b = got[name][0, 0], want[name][0, 0]
        assert a.dtype.names == b.dtype.names
        for field in a.dtype.names:
            x, y = a[field], b[field]
            if x.dtype == object:
                assert [str(v) for v in x.ravel()] == [str(v) for v in y.ravel()]
            else:
                np.testing.assert_array_equal(x, y)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """Four trials, one without truth (its frames table lacks the column)."""
    from tests.recording_fixtures import T0, write_trial

    folder = tmp_path_factory.mktemp("study")
    for k in range(3):
        write_recording(folder / f"S0{k + 1}_indoor_t01.mcap", seconds=1.0)
    write_trial(folder / "S09_indoor_t01.mcap", [(T0, "LG", "operator")], frames=30)
    return folder


@pytest.mark.parametrize("fmt", ["parquet", "csv", "mat"])
def test_a_study_is_written_trial_by_trial_as_the_joined_tables(study, tmp_path, fmt, monkeypatch):
    import pyarrow.parquet as pq
    from scipy.io import loadmat

    joined, _ = export.corpus_tables([study], every_file=True)
    export.write(joined, tmp_path / "joined", fmt)

    def refused(*args, **kwargs):
        raise AssertionError("the study's tables were joined in memory")

    monkeypatch.setattr(export, "corpus_tables", refused)
    written, rows, _ = export.write_corpus([study], tmp_path / "streamed", fmt, every_file=True)
    assert rows == {name: len(df) for name, df in joined.items()}
    assert not (tmp_path / "streamed" / ".export-spool").exists()
    if fmt == "mat":
        got = loadmat(tmp_path / "streamed" / "walkcap.mat")
        want = loadmat(tmp_path / "joined" / "walkcap.mat")
        for name in export.TABLES:
            a, b = got[name][0, 0], want[name][0, 0]
            assert a.dtype.names == b.dtype.names
            for field in a.dtype.names:
                assert [str(v) for v in a[field].ravel()] == [str(v) for v in b[field].ravel()]
        return
    for name in export.TABLES:
        a, b = tmp_path / "streamed" / f"{name}.{fmt}", tmp_path / "joined" / f"{name}.{fmt}"
        if fmt == "csv":
            assert a.read_text() == b.read_text(), name
        else:
            pd.testing.assert_frame_equal(pd.read_parquet(a), pd.read_parquet(b))
    if fmt == "parquet":  # the IMU table has the same columns in every trial: one trial a group
        assert pq.ParquetFile(tmp_path / "streamed" / "imu.parquet").num_row_groups >= 3


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("trial") / "S07_indoor_t03.mcap"
    write_recording(path, seconds=2.0)
    return path


def _in_blocks(monkeypatch, block: int, rows: int) -> None:
    from capture.corpus import trial_pass

    monkeypatch.setattr(trial_pass, "BLOCK", block)
    monkeypatch.setattr(export, "ROW_GROUP", rows)


def test_tables_made_in_blocks_are_the_ones_made_in_one(recording, monkeypatch):
    """Rows spooled 7 at a time and tables made 16 rows at a time, joined: the tables of
    one block each."""
    _in_blocks(monkeypatch, 10**9, 10**9)
    whole = export.tables(recording)
    _in_blocks(monkeypatch, 7, 16)
    blocks = export.tables(recording)
    assert len(whole["frames"]) > 64 and len(whole["imu"]) > 64
    for name, df in whole.items():
        pd.testing.assert_frame_equal(blocks[name], df, check_exact=True)


def test_frame_messages_far_behind_their_rows_are_laid_over_the_spooled_rows(
    recording, tmp_path, monkeypatch
):
    from capture.corpus import trial_pass
    from capture.recording import topics as T
    from capture.recording.frames import FrameJoin, frame_rows
    from capture.recording.reader import frame_table, open_recording
    from tests.capture.recording.test_frame_join import _same

    rec = open_recording(recording)
    whole, changes = frame_table(rec)
    messages = list(rec.messages([t for t in trial_pass.TrialPass.TOPICS if t in rec.topics]))
    late = {T.FUSED, T.TF}  # every fused decision and orientation long after its frame
    k = int(whole.index[20])  # and one frame's own CNN output and preprocessing
    own = [m for m in messages if m.topic in (T.CNN, T.PREPROCESS) and m.data["frame_index"] == k]
    delayed = [m for m in messages if m.topic not in late and m not in own]
    delayed += [m for m in messages if m.topic in late] + own
    monkeypatch.setattr(trial_pass, "BLOCK", 7)
    trial = trial_pass.TrialPass.gather(
        rec, delayed, tmp_path, export._IMU_FIELDS, FrameJoin(lateness=2)
    )
    with trial:
        assert trial.frames.late and trial.frames.spool.rows < len(whole)  # rows from late ones
        blocks = list(trial.frame_blocks(16))
        summary = trial.frame_summary()
    assert [len(b["index"]) for b in blocks[:-1]] == [16] * (len(blocks) - 1)
    joined = {
        key: [v for b in blocks for v in b[key]]
        if isinstance(blocks[0][key], list)
        else np.concatenate([b[key] for b in blocks])
        for key in blocks[0]
    }
    _same(frame_rows(joined, changes, has_truth=whole.has_truth), whole)
    assert summary.rows == len(whole) and summary.earliest_ns == int(whole.time_ns.min())


@pytest.mark.parametrize("fmt", ["parquet", "csv", "mat"])
def test_a_trial_written_as_it_is_read_is_the_files_of_its_tables_written_whole(
    recording, tmp_path, monkeypatch, fmt
):
    _in_blocks(monkeypatch, 7, 16)
    written, rows = export.write_trial(recording, tmp_path / "streamed", fmt)
    tables = export.tables(recording)
    export.write(tables, tmp_path / "whole", fmt)
    assert rows == {name: len(df) for name, df in tables.items()}
    assert sorted(p.name for p in (tmp_path / "streamed").iterdir()) == sorted(
        p.name for p in written
    )  # nothing of the spool is left
    for path in written:
        a, b = path.read_bytes(), (tmp_path / "whole" / path.name).read_bytes()
        if fmt == "mat":  # the header says when the file was made
            a, b = a[128:], b[128:]
        assert a == b, path.name
