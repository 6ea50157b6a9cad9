"""Recordings as tables: pandas DataFrames in Python, Parquet, CSV or MATLAB files.

    from capture.corpus import export
    t = export.tables("S01_indoor_t01.mcap")       # {"frames": DataFrame, "imu": ..., ...}
    t["frames"][["time_s", "label", "decision"]]
    t, corpus = export.corpus_tables(["recordings/"])   # one file per trial, rows concatenated
    export.write(t, "out/", "parquet")              # frames.parquet, imu.parquet, ...

Tables (every row names its file, recording id, subject, condition and trial; every column
is described in docs/export.md):
- frames: one row per camera frame: frame_index; time_ns (sample time, session clock),
  unix_time_ns, time_s (seconds since the recording's start: its earliest time, receive or
  sample, the same origin in every table of the file); label (the operator's mode in
  force, undos applied), truth (simulator, when recorded); p_<MODE> (CNN softmax) and
  cnn_decision; posterior_<MODE> (fused HMM posterior for this frame), decision (the fused
  decision for this frame) and decision_at_frame (the frame whose arrival produced it),
  voted and voted_at_frame; terrain_* (terrain features); preprocess_flag, oriented,
  cloud_points; qw, qx, qy, qz (the camera's orientation at the frame time).
- imu: one row per IMU sample (time_ns: sample time, host_time_ns: arrival).
- labels: every recorded change, undos included, with in_reference (whether it defines
  `label`) and undone (taken back by a later undo).
- events: device events and operator markers, in time order.
- gait: heel contacts and toe offs of the instrumented leg, in time order: event, source
  ("imu": the detector's, /gait; "simulator": the walk's truth, /sim/gait), mode (the
  terrain under the foot, where known).
- trials: one row per file: identity, lineage, session form, model; start_time_ns and
  end_time_ns (session clock), start_unix_time_ns and end_unix_time_ns, duration_s; per
  sensor stream its gaps, items missing and late deliveries (capture.recording.gaps).
Modes are names (LG, US, DS, UR, DR); "" where there is none.
The frames' terrain and locomotion columns are the two references eval uses: terrain,
what the image shows (the simulator's truth, else the labels made offline in `replay
--tui` over the keys, else ""); locomotion, the mode keyed live (undos applied, offline
labels not).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from capture.corpus import jobs
from capture.corpus import selection as corpus_mod
from capture.corpus.imu_columns import ImuColumns
from capture.corpus.trial_pass import FEATURE_FIELDS, FrameSummary, TrialPass
from capture.errors import CaptureError
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.frames import FrameTable, frame_rows, mode_names
from capture.recording.gaps import TOPICS as GAP_TOPICS
from capture.recording.gaps import recording_loss
from capture.recording.lineage import describe
from devices import clock
from devices.files import check_replaceable
from devices.frames import MODES
from devices.xbus import DEFAULT_OUTPUTS

TABLES = ("frames", "imu", "labels", "events", "gait", "trials")
FORMATS = ("parquet", "csv", "mat")
# The trials table's session and software columns, the same in every corpus whatever its
# files' metadata holds: field -> pandas dtype (missing: NA, or "" for text).
SESSION_COLUMNS = {
    "height_m": "float64",
    "weight_kg": "float64",
    "age": "Int64",
    "sex": "object",
    "amputee": "boolean",
    "side": "object",
    "residual_limb_cm": "float64",
    "notes": "object",
    "operator": "object",
    "supersedes": "object",
}
SOFTWARE_COLUMNS = {
    "model_hash": "object",
    "model_path": "object",
    "walkcap_version": "object",
    "fusion_window": "Int64",
    "fusion_vote_delay": "Int64",
}


def _pd():
    try:
        import pandas
    except ModuleNotFoundError:  # pragma: no cover - a dependency of walkcap
        raise CaptureError("export needs pandas: pip install pandas pyarrow") from None
    return pandas


def tables(path: str | os.PathLike) -> dict:
    """The tables of one recording as pandas DataFrames (see the module's docstring)."""
    pd = _pd()
    with TrialPass.read(path, None, _IMU_FIELDS) as trial:
        return {name: _joined(pd, list(blocks)) for name, blocks in table_blocks(trial)}


def table_blocks(trial: TrialPass, rows: int | None = None):
    """(name, its DataFrames) for each table of the recording read by `trial`, in TABLES
    order, each table in DataFrames of `rows` rows (default ROW_GROUP; the last may be
    shorter): what tables() joins and the writers write one at a time. Each table's
    DataFrames are to be taken before the next table's."""
    pd = _pd()
    rows = rows or ROW_GROUP
    rec = trial.rec
    member = describe(rec)
    subject, condition, trial_number = rec.trial
    offset = rec.unix_offset_ns
    identity = {
        "file": rec.path.name,
        "recording_id": member.id,
        "subject": subject,
        "condition": condition,
        "trial": trial_number,
    }
    summary = trial.frame_summary()
    changes = trial.changes
    events = sorted(trial.events, key=lambda e: int(e.get("time_ns", 0)))  # in time order
    gait = sorted(trial.gait, key=lambda e: int(e["time_ns"]))
    gait_t = np.array([int(e["time_ns"]) for e in gait], dtype=np.int64)
    label_t = np.array([c[0] for c in changes], dtype=np.int64)
    event_t = np.array([int(e.get("time_ns", 0)) for e in events], dtype=np.int64)
    # time_s counts from the recording's start: its earliest time, receive or sample (an
    # IMU sample's time precedes its arrival), so that no row has a negative time
    earliest = [summary.earliest_ns, trial.imu_earliest_ns, rec.start_ns]
    earliest += [int(a.min()) for a in (label_t, event_t, gait_t) if len(a)]
    t0 = min((t for t in earliest if t is not None), default=0)
    has_truth = T.TRUTH in rec.topics

    def frames():
        for block in trial.frame_blocks(rows):
            table = frame_rows(block, changes, has_truth=has_truth)
            columns = _frame_columns(table, offset, t0, summary.numeric)
            yield _frame(pd, identity, columns, len(table))

    def imu():
        for block in trial.imu_blocks(rows):
            columns = _imu_columns(block, block.times(), offset, t0)
            yield _frame(pd, identity, columns, len(block))

    def one(columns: dict, n: int):
        yield _frame(pd, identity, columns, n)

    yield "frames", frames()
    yield "imu", imu()
    yield "labels", one(_label_columns(changes, label_t, offset, t0), len(changes))
    yield "events", one(_timed_columns(events, event_t, offset, t0, _EVENT_COLUMNS), len(events))
    yield "gait", one(_timed_columns(gait, gait_t, offset, t0, _GAIT_COLUMNS), len(gait))
    yield "trials", iter([_trials_frame(pd, _trial_row(rec, member, identity, summary))])


def _joined(pd, dfs: list):
    """A table's DataFrames as one."""
    return dfs[0] if len(dfs) == 1 else pd.concat(dfs, ignore_index=True)


def _trials_frame(pd, row: dict):
    """One file's trials row with its fixed columns typed, so that every file's row (and
    so every corpus's table) has the same columns and dtypes."""
    df = pd.DataFrame([row])
    typed = {f"session_{k}": t for k, t in SESSION_COLUMNS.items()} | SOFTWARE_COLUMNS
    for stream in GAP_TOPICS.values():
        typed |= {f"{stream}_{k}": "Int64" for k in ("gaps", "missing", "late")}
        typed[f"{stream}_longest_gap_s"] = "float64"
    for column, dtype in typed.items():
        df[column] = pd.array([_typed(row[column], dtype)], dtype=dtype)
    return df


def _typed(value, dtype: str):
    """A metadata value as the column's type; None when absent or not of that type (a
    damaged or foreign file's metadata never breaks the table)."""
    if value is None or value == "":
        return "" if dtype == "object" else None
    try:
        if dtype == "float64":
            return float(value)
        if dtype == "Int64":
            return None if isinstance(value, bool) else int(value)
        if dtype == "boolean":
            return value if isinstance(value, bool) else None
    except (TypeError, ValueError):
        return None
    if isinstance(value, list):  # supersedes: the ids, space-separated
        return " ".join(str(v) for v in value)
    return _json_text(value) if isinstance(value, dict) else str(value)


def _frame(pd, identity: dict, columns: dict, n: int):
    df = pd.DataFrame(columns)
    for k, v in reversed(list(identity.items())):
        df.insert(0, k, pd.Series([v] * n, dtype=_identity_dtype(pd, k)))
    return df


def _frame_columns(
    table: FrameTable, offset: int | None, t0: int, numeric: dict[str, bool] | None = None
) -> dict:
    """The frames table's columns from the per-frame table (capture.recording.frames);
    `numeric`: which terrain feature fields are numbers over the whole table, when
    `table` is a block of it (else taken from `table`)."""
    frames = {"frame_index": table.index, "time_ns": table.time_ns}
    frames.update(_clock(table.time_ns, offset, t0))
    frames["label"] = mode_names(table.labels)
    if table.has_truth:
        frames["truth"] = mode_names(table.truth)
    frames["terrain"] = (
        mode_names(table.terrain) if table.terrain is not None else [""] * len(table)
    )
    frames["locomotion"] = mode_names(table.locomotion)
    for j, mode in enumerate(MODES):
        frames[f"p_{mode}"] = table.probabilities[:, j]
    frames["cnn_decision"] = mode_names(table.cnn_decision)
    for j, mode in enumerate(MODES):
        frames[f"posterior_{mode}"] = table.posterior[:, j]
    frames["decision"] = mode_names(table.decision)
    frames["decision_at_frame"] = _frames_at(table.decision_at)
    frames["voted"] = mode_names(table.voted)
    frames["voted_at_frame"] = _frames_at(table.voted_at)
    for name in FEATURE_FIELDS:
        values = [f.get(name) for f in table.features]
        frames[f"terrain_{name}"] = _column(values, None if numeric is None else numeric[name])
    frames["preprocess_flag"] = list(table.flag)
    frames["oriented"] = [bool(x) for x in table.oriented]
    frames["cloud_points"] = _ints(table.cloud_points)
    for j, name in enumerate(("qw", "qx", "qy", "qz")):
        frames[name] = table.quaternion[:, j]
    return frames


# an IMU sample's fields the table takes, in this order
_IMU_FIELDS = ("time_ns", "host_time_ns", *DEFAULT_OUTPUTS)


def _imu_columns(imu: ImuColumns, imu_t: np.ndarray, offset: int | None, t0: int) -> dict:
    imu_cols = {"time_ns": imu_t, "host_time_ns": imu.ints_of("host_time_ns")}
    imu_cols.update(_clock(imu_t, offset, t0))
    imu_cols["packet_counter"] = imu.ints_of("packet_counter")
    imu_cols["sample_time_fine"] = imu.ints_of("sample_time_fine")
    for field, names in (
        ("quaternion", ("qw", "qx", "qy", "qz")),
        ("acceleration", ("acc_x", "acc_y", "acc_z")),
        ("rate_of_turn", ("gyr_x", "gyr_y", "gyr_z")),
    ):
        values = imu.vector(field)
        for j, name in enumerate(names):
            imu_cols[name] = values[:, j].copy()
    imu_cols["status_word"] = imu.ints_of("status_word")
    return imu_cols


def _label_columns(changes: list, label_t: np.ndarray, offset: int | None, t0: int) -> dict:
    in_force = set(L.effective_changes(changes))
    undone = L.undone(changes)
    labels = {"time_ns": label_t}
    labels.update(_clock(label_t, offset, t0))
    labels["mode"] = [c[1] for c in changes]
    labels["source"] = [c[2] for c in changes]
    labels["is_undo"] = [L.is_undo(c[2]) for c in changes]
    labels["undone"] = [k in undone for k in range(len(changes))]
    labels["in_reference"] = [c in in_force for c in changes]
    return labels


# each table of timed records: its columns after the clock's, and how a record gives each
_EVENT_COLUMNS = {
    "device": lambda e: str(e.get("device", "")),
    "kind": lambda e: str(e.get("kind", "")),
    "message": lambda e: str(e.get("message", "")),
    "details": lambda e: _json_text(e.get("details") or {}),
}
_GAIT_COLUMNS = {
    "event": lambda e: str(e.get("event", "")),
    "source": lambda e: str(e.get("source", "")),
    "mode": lambda e: str(e.get("mode") or ""),
}


def _timed_columns(
    records: list[dict], t: np.ndarray, offset: int | None, t0: int, columns: dict
) -> dict:
    """A table of timed records (events, gait events): their times on every clock, then
    `columns` (name -> the value of a record)."""
    cols = {"time_ns": t}
    cols.update(_clock(t, offset, t0))
    for name, value in columns.items():
        cols[name] = [value(r) for r in records]
    return cols


def _trial_row(rec, member, identity: dict, frames: FrameSummary) -> dict:
    offset = rec.unix_offset_ns
    trials = {**identity}
    trials.update(
        {
            "kind": member.kind,
            "source_id": member.source_id,
            "source_name": member.source_name,
            "derived_how": member.how,
            "complete": rec.complete,
            "start_time_ns": rec.start_ns,
            "end_time_ns": rec.end_ns,
            "start_unix_time_ns": rec.unix_time_ns(rec.start_ns),
            "end_unix_time_ns": rec.unix_time_ns(rec.end_ns),
            "duration_s": rec.duration_s,
            "frames": frames.rows,
            # frames left undecided: their IMU orientation was too old to level the cloud
            "stale_orientation_frames": frames.stale,
            "unix_offset_ns": offset,
        }
    )
    # a fixed set of columns whatever the metadata holds (SESSION_COLUMNS; absent: NA)
    session, software = rec.meta.session, rec.meta.software
    for key in SESSION_COLUMNS:
        trials[f"session_{key}"] = session.value(key)
    for key in SOFTWARE_COLUMNS:
        trials[key] = software.value(key)

    # loss by the one definition of the live alarms and `walkcap info` (capture.recording.gaps)
    # (a stream the file does not hold: NA in its columns, which are always there)
    losses = recording_loss(rec)
    for topic, stream in GAP_TOPICS.items():
        loss = losses.get(topic)
        trials[f"{stream}_gaps"] = None if loss is None else len(loss.gaps)
        trials[f"{stream}_missing"] = None if loss is None else loss.missing
        trials[f"{stream}_longest_gap_s"] = None if loss is None else loss.longest_s
        trials[f"{stream}_late"] = None if loss is None else len(loss.late)
    return trials


def _files_to_export(paths, replays: bool, every_file: bool):
    """The recordings an export reads and the corpus they came from: one file per trial
    (capture.corpus.selection.select), or `every_file` as found; refused when none."""
    if every_file:
        files = corpus_mod.recording_files(paths)
        chosen = corpus_mod.Corpus([], [])
    else:
        chosen = corpus_mod.select(paths, replays=replays)
        files = chosen.files
    if not files:
        raise chosen.nothing_left("nothing to export")
    return files, chosen


def corpus_tables(
    paths: Iterable[str | os.PathLike],
    *,
    replays: bool = False,
    every_file: bool = False,
    progress: bool = False,
    cluster: str | None = None,
):
    """Tables of many recordings, rows concatenated, and the corpus they came from: one
    file per trial (capture.corpus.selection.select), or `every_file` as found. `cluster`: a Ray
    cluster's address or "local", one task a recording (capture.corpus.jobs)."""
    pd = _pd()
    files, chosen = _files_to_export(paths, replays, every_file)
    parts: dict[str, list] = {name: [] for name in TABLES}
    where = jobs.choose(cluster)
    tasks = [jobs.Task(Path(f).name, tables, (jobs.task_path(where, f),)) for f in files]
    per_file = jobs.run(
        tasks,
        where,
        desc="export",
        unit="recording",
        show_progress=progress and len(files) > 1,
    )
    for file_tables in per_file:
        for name, df in file_tables.items():
            parts[name].append(df)
    out = {}
    for name, dfs in parts.items():
        nonempty = [d for d in dfs if len(d)] or dfs[:1]
        out[name] = pd.concat(nonempty, ignore_index=True) if len(nonempty) > 1 else nonempty[0]
    return out, chosen


def spool(path: str, folder: str) -> dict[str, int]:
    """One corpus job (capture.corpus.jobs): a recording's tables as Parquet files in
    `folder`, one a table, written as they are made; the rows of each."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    with TrialPass.read(path, out, _IMU_FIELDS) as trial:
        return _spool_frames(out, table_blocks(trial))


def _spool_frames(folder: Path, named) -> dict[str, int]:
    """Tables given as (name, DataFrame or DataFrames) into Parquet files in `folder`, in
    row groups of ROW_GROUP rows; the rows of each."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = {}
    for name, frames in named:
        frames = [frames] if hasattr(frames, "columns") else frames
        rows[name] = _write_parquet_frames(folder / f"{name}.parquet", frames)
    return rows


def write_corpus(
    paths: Iterable[str | os.PathLike],
    out: str | os.PathLike,
    fmt: str = "parquet",
    *,
    replays: bool = False,
    every_file: bool = False,
    progress: bool = False,
    cluster: str | None = None,
):
    """corpus_tables() written by write(), trial by trial: each recording's tables go to a
    spool folder as they are made, and each table's file is then written from those one
    trial at a time (tables whose columns differ between trials, a few small ones, are
    joined in memory as corpus_tables joins them). Memory does not grow with the number
    of trials. (written files, rows per table, the corpus)."""
    import shutil

    pd = _pd()
    if fmt not in FORMATS:
        raise CaptureError(f"export format {fmt!r}: one of {', '.join(FORMATS)}")
    files, chosen = _files_to_export(paths, replays, every_file)
    folder = _folder(out)
    if len(files) == 1 and not cluster:  # one trial's tables, written as they are made
        written, rows = write_trial(files[0], folder, fmt)
        return written, rows, chosen
    work = folder / ".export-spool"
    shutil.rmtree(work, ignore_errors=True)
    try:
        parts = [work / f"{k:06d}" for k in range(len(files))]
        show = progress and len(files) > 1
        if cluster:  # a node need not see this folder: each trial's tables come back whole
            where = jobs.choose(cluster)
            tasks = [jobs.Task(Path(f).name, tables, (jobs.task_path(where, f),)) for f in files]
            rows = dict.fromkeys(TABLES, 0)

            def spool_tables(i: int, trial_tables: dict) -> None:
                for name, n in _spool_frames(parts[i], trial_tables.items()).items():
                    rows[name] += n

            jobs.run(
                tasks,
                where,
                desc="export",
                unit="recording",
                show_progress=show,
                on_result=spool_tables,
                keep_results=False,
            )
        else:
            tasks = [
                jobs.Task(Path(f).name, spool, (str(f), str(p)))
                for f, p in zip(files, parts, strict=True)
            ]
            per_file = jobs.run(
                tasks, jobs.LOCAL, desc="export", unit="recording", show_progress=show
            )
            rows = {name: sum(r[name] for r in per_file) for name in TABLES}
        written = _write_spooled(pd, parts, folder, fmt)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return written, rows, chosen


def write_trial(
    path: str | os.PathLike, out: str | os.PathLike, fmt: str = "parquet"
) -> tuple[list[Path], dict[str, int]]:
    """One recording's tables written into folder `out` as they are made, in blocks of
    ROW_GROUP rows: the same files write(tables(path), out, fmt) gives, in memory that
    does not grow with the trial's length (its frames and IMU samples go through a spool
    beside the output). (written files, rows per table)."""
    if fmt not in FORMATS:
        raise CaptureError(f"export format {fmt!r}: one of {', '.join(FORMATS)}")
    folder = _folder(out)
    rows: dict[str, int] = {}

    def counted(name: str, blocks):
        rows[name] = 0
        for df in blocks:
            rows[name] += len(df)
            yield df

    try:
        trial = TrialPass.read(path, folder, _IMU_FIELDS)
    except OSError as e:  # the spool beside the output: a full disk
        first = folder / ("walkcap.mat" if fmt == "mat" else f"{TABLES[0]}.{fmt}")
        raise CaptureError(
            f"{first}: not written (the rows read go beside it first: {e.strerror or e}); "
            "nothing of the export is left"
        ) from None
    with trial:
        named = ((name, counted(name, blocks)) for name, blocks in table_blocks(trial))
        if fmt == "mat":
            written = [_whole(folder / "walkcap.mat", lambda p: _write_mat_spooled(p, named))]
        else:
            written = _write_tables(named, folder, fmt)
    return written, rows


def _folder(out: str | os.PathLike) -> Path:
    folder = Path(out)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CaptureError(f"cannot create {folder}: {e.strerror}") from None
    return folder


class _Spooled:
    """One table of every trial, from the spool: whole (joined as corpus_tables joins
    them) or trial by trial when every trial has the same columns."""

    def __init__(self, pd, parts: list[Path], name: str) -> None:
        import pyarrow.parquet as pq

        self.pd = pd
        self.files = [p / f"{name}.parquet" for p in parts]
        self.nonempty = [f for f in self.files if pq.ParquetFile(f).metadata.num_rows]
        # as corpus_tables joins them, an empty table adds nothing, not even its columns
        schemas = [pq.read_schema(f).remove_metadata() for f in self.nonempty or self.files[:1]]
        self.same = all(s.equals(schemas[0]) for s in schemas)

    def frames(self):
        """Each trial's table a row group at a time (the empty ones only when all are
        empty)."""
        import pyarrow.parquet as pq

        for f in self.nonempty or self.files[:1]:
            groups = pq.ParquetFile(f)
            for k in range(max(groups.num_row_groups, 1)):
                table = groups.read_row_group(k) if groups.num_row_groups else groups.read()
                yield table.to_pandas()

    def whole(self):
        dfs = list(self.frames())
        return self.pd.concat(dfs, ignore_index=True) if len(dfs) > 1 else dfs[0]


def _write_spooled(pd, parts: list[Path], folder: Path, fmt: str) -> list[Path]:
    if fmt == "mat":  # a MATLAB variable holds a column whole: one column in memory at a time
        spooled = {name: _Spooled(pd, parts, name) for name in TABLES}
        tables_ = {
            name: _columns_of(t.nonempty or t.files[:1]) if t.same else t.whole()
            for name, t in spooled.items()
        }
        return [_whole(folder / "walkcap.mat", lambda p: _write_mat(p, tables_))]
    written: list[Path] = []
    for name in TABLES:
        table = _Spooled(pd, parts, name)
        path = folder / f"{name}.{fmt}"
        if not table.same:
            written.append(_write_one(path, table.whole(), fmt))
            continue
        if fmt == "parquet":
            write_table = lambda p, t=table: _write_parquet_frames(p, t.frames())  # noqa: E731
        else:
            write_table = lambda p, t=table: _csv_parts(p, t.frames())  # noqa: E731
        written.append(_whole(path, write_table))
    return written


def _write_parquet_frames(path: Path, frames) -> int:
    """DataFrames of one table into a Parquet file, in row groups of up to ROW_GROUP rows,
    each converted to Arrow on its own: one group's copy in memory at a time. The schema is
    the first one's. Read back, it is the tables joined. The rows written."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    writer, rows = None, 0
    try:
        for df in frames:
            if writer is None:
                writer = pq.ParquetWriter(path, pa.Schema.from_pandas(df, preserve_index=False))
            for start in range(0, max(len(df), 1), ROW_GROUP):
                part = df.iloc[start : start + ROW_GROUP]
                table = pa.Table.from_pandas(part, schema=writer.schema, preserve_index=False)
                writer.write_table(table.replace_schema_metadata(writer.schema.metadata))
            rows += len(df)
    finally:
        if writer is not None:
            writer.close()
    return rows


def _write_tables(named, folder: Path, fmt: str) -> list[Path]:
    """(name, DataFrames) of each table, in turn, into `name.fmt` (parquet or csv)."""
    written: list[Path] = []
    for name, frames in named:
        path = folder / f"{name}.{fmt}"
        if fmt == "parquet":
            write_table = lambda p, f=frames: _write_parquet_frames(p, f)  # noqa: E731
        else:
            write_table = lambda p, f=frames: _csv_parts(p, f)  # noqa: E731
        written.append(_whole(path, write_table))
    return written


def _csv_parts(path: Path, frames) -> None:
    with open(path, "w", newline="") as f:
        for k, df in enumerate(frames):
            df.to_csv(f, index=False, header=k == 0, chunksize=CSV_ROWS)


def _write_one(path: Path, df, fmt: str) -> Path:
    if fmt == "parquet":
        return _whole(path, lambda p: _write_parquet(p, df))
    return _whole(path, lambda p: df.to_csv(p, index=False, chunksize=CSV_ROWS))


def write(tables_: dict, out: str | os.PathLike, fmt: str = "parquet") -> list[Path]:
    """Write the tables into folder `out`: one file per table (parquet, csv), or one
    walkcap.mat with a struct per table whose fields are the columns (MATLAB)."""
    if fmt not in FORMATS:
        raise CaptureError(f"export format {fmt!r}: one of {', '.join(FORMATS)}")
    folder = Path(out)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CaptureError(f"cannot create {folder}: {e.strerror}") from None
    if fmt == "mat":
        return [_whole(folder / "walkcap.mat", lambda p: _write_mat(p, tables_))]
    written: list[Path] = []
    for name, df in tables_.items():
        path = folder / f"{name}.{fmt}"
        if fmt == "parquet":
            write_table = lambda p, df=df: _write_parquet(p, df)  # noqa: E731
        else:
            write_table = lambda p, df=df: df.to_csv(p, index=False, chunksize=CSV_ROWS)  # noqa: E731
        try:
            written.append(_whole(path, write_table))
        except ImportError:
            raise CaptureError("Parquet needs pyarrow: pip install pyarrow") from None
        except CaptureError as e:
            done = f"; written before it: {', '.join(p.name for p in written)}" if written else ""
            raise CaptureError(f"{e}{done}") from None
    return written


ROW_GROUP = 50_000  # rows a Parquet row group (and a table's block in memory) holds
# rows pandas formats at once into CSV text: the text of a whole block would take several
# times the block's memory
CSV_ROWS = 4096


def _write_parquet(path: Path, df) -> None:
    """The table in row groups of ROW_GROUP rows (_write_parquet_frames)."""
    _write_parquet_frames(path, [df])


def _write_mat(path: Path, tables_: dict) -> None:
    """One walkcap.mat, a struct per table (a DataFrame, or a _SpooledColumns), the
    tables converted and written one by one, a spooled table a column at a time: never
    the whole trial's MATLAB copy in memory at once."""
    from scipy.io import savemat

    with open(path, "wb") as f:  # savemat writes the file's header at its start only
        for name, table in tables_.items():
            savemat(f, {name: _mat_struct(table)}, oned_as="column")


# tables large enough to go through a Parquet spool on their way to a .mat file
_SPOOLED_FOR_MAT = ("frames", "imu")


def _write_mat_spooled(path: Path, named) -> None:
    """(name, DataFrames) of each table into one .mat file at `path`: the large tables
    through Parquet files beside it, read back a column at a time."""
    import shutil

    work = path.with_name(f".{path.stem}.spool")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    try:
        tables_ = {}
        for name, frames in named:
            if name in _SPOOLED_FOR_MAT:
                _write_parquet_frames(work / f"{name}.parquet", frames)
                tables_[name] = _columns_of([work / f"{name}.parquet"])
            else:
                tables_[name] = _joined(_pd(), list(frames))
        _write_mat(path, tables_)
    finally:
        shutil.rmtree(work, ignore_errors=True)


class _SpooledColumns:
    """A table in Parquet files (one after another), read a column at a time."""

    def __init__(self, files: list[Path]) -> None:
        import pyarrow.parquet as pq

        self.files = files
        self.columns = list(pq.read_schema(files[0]).names)

    def column(self, name: str):
        import pyarrow.parquet as pq

        parts = [pq.read_table(f, columns=[name]).to_pandas()[name] for f in self.files]
        return parts[0] if len(parts) == 1 else _pd().concat(parts, ignore_index=True)


def _columns_of(files: list[Path]) -> _SpooledColumns:
    return _SpooledColumns(files)


class _MatColumn:
    """A spooled column that becomes its MATLAB values when scipy's writer takes it."""

    def __init__(self, table: _SpooledColumns, name: str) -> None:
        self.table, self.name = table, name

    def __array__(self, dtype=None, copy=None):
        return _mat_values(self.table.column(self.name))


def _whole(path: Path, write) -> Path:
    """`write(tmp)` beside `path`, renamed into place once whole: a full disk leaves no
    truncated table under the table's name, and the error names the file."""
    check_replaceable(path)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")  # savemat wants .mat
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise CaptureError(
            f"{path}: not written ({e.strerror or e}); nothing of it is left"
        ) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


# ---- helpers -----------------------------------------------------------------------------


def _clock(times: np.ndarray, offset: int | None, t0: int) -> dict:
    return {
        "unix_time_ns": _ints([None if offset is None else int(t) + offset for t in times]),
        "time_s": clock.seconds(times.astype(np.int64) - t0) if len(times) else np.zeros(0),
    }


def _frames_at(frames: np.ndarray):
    """Frame numbers, -1 (none) as a gap."""
    return _ints([int(k) if k >= 0 else None for k in frames])


def _ints(values: list):
    """An integer column that may have gaps: pandas' nullable Int64."""
    pd = _pd()
    return pd.array(values, dtype="Int64")


def _column(values: list, numbers: bool | None = None):
    """Numbers as float (None -> NaN), anything else as text (None -> ""); `numbers`:
    whether the whole column is numbers (None: these values say)."""
    if numbers is None:
        numbers = all(
            v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values
        )
    if numbers:
        return np.array([np.nan if v is None else float(v) for v in values], dtype=float)
    return ["" if v is None else str(v) for v in values]


def _json_text(value) -> str:
    return T.encode_json(value).decode() if isinstance(value, dict) else str(value)


def _identity_dtype(pd, key: str):
    return "Int64" if key == "trial" else object


_MATLAB_NAME = re.compile(r"[^A-Za-z0-9_]")


def matlab_name(name: str) -> str:
    """A valid MATLAB identifier: letters, digits, _; starts with a letter; <= 63 chars."""
    out = _MATLAB_NAME.sub("_", name)
    if not out or not out[0].isalpha():
        out = "x" + out
    return out[:63]


def _mat_struct(table) -> dict:
    """A DataFrame (or _SpooledColumns) as a MATLAB struct of columns (_mat_values); a
    spooled table's columns are read as the writer reaches each."""
    if isinstance(table, _SpooledColumns):
        return {matlab_name(str(c)): _MatColumn(table, c) for c in table.columns}
    return {matlab_name(str(column)): _mat_values(table[column]) for column in table.columns}


def _mat_values(s):
    """A column as MATLAB values: integers as int64 (double, gaps NaN, where a value is
    missing), other numbers as double, booleans as logical (a flag that may be unknown as
    double: 1, 0, NaN), text as cell arrays of char."""
    from pandas.api.types import is_bool_dtype, is_integer_dtype, is_numeric_dtype

    if isinstance(s.dtype, _pd().BooleanDtype):  # a flag that may be unknown: 1, 0 or NaN
        return s.astype("float64").to_numpy(na_value=np.nan)
    if is_bool_dtype(s.dtype):
        return s.to_numpy(dtype=bool)
    if is_integer_dtype(s.dtype) and not s.isna().any():
        return s.to_numpy(dtype=np.int64)  # ns times need all 64 bits
    if is_numeric_dtype(s.dtype):
        return s.astype("float64").to_numpy(na_value=np.nan)
    return np.array(["" if v is None else str(v) for v in s], dtype=object)
