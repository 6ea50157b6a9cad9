"""One pass over a recording for the export: its per-frame rows and IMU samples in blocks,
kept in a spool (a file beside the output, or memory) as they are finished, and what
every block needs to be made a table (the earliest time, the label changes, the frames'
late messages, which feature fields are numbers), so that no table of a long trial is
held whole.

    with TrialPass.read("S01_indoor_t01.mcap", spool_folder) as trial:
        for block in trial.frame_blocks(rows=50_000):     # FrameJoin columns, frame order
            ...
        for block in trial.imu_blocks(rows=50_000):       # ImuColumns
            ...
"""

from __future__ import annotations

import os
import pickle
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from capture.corpus.imu_columns import ImuColumns
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.frames import FrameJoin, _Columns, lay_late
from capture.recording.reader import open_recording

BLOCK = 4096  # rows gathered before they go to the spool
# the terrain feature fields the frames table has, in its order (export's columns)
FEATURE_FIELDS = (
    "kind",
    "slope_deg",
    "ahead_slope_deg",
    "riser_m",
    "tread_m",
    "direction",
    "steps",
    "inlier_fraction",
    "residual_m",
    "tilt_offset_deg",
)


class Spool:
    """Blocks kept in the order added: pickled one after another into a file in `folder`
    (the system's temporary folder when None; deleted on close), or in memory."""

    def __init__(self, folder: str | os.PathLike | None = None, *, memory: bool = False) -> None:
        self._blocks: list | None = None
        self._file = None
        if memory:
            self._blocks = []
        else:
            self._file = tempfile.TemporaryFile(dir=folder, prefix=".walkcap-spool-")
        self.rows = 0

    def add(self, block, rows: int) -> None:
        self.rows += rows
        if self._blocks is not None:
            self._blocks.append(block)
        else:
            pickle.dump(block, self._file, protocol=pickle.HIGHEST_PROTOCOL)

    def blocks(self) -> Iterator:
        if self._blocks is not None:
            yield from self._blocks
            return
        self._file.flush()
        self._file.seek(0)
        while True:
            try:
                yield pickle.load(self._file)
            except EOFError:
                return

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
        self._blocks = None


class FrameRows:
    """The per-frame join (FrameJoin) of one pass, its finished rows spooled in blocks as
    they come; read back, the messages that came after their frame was finished are laid
    over the rows, as FrameJoin.table() lays them."""

    def __init__(self, spool: Spool, join: FrameJoin | None = None) -> None:
        self.spool = spool
        self.join = join or FrameJoin()
        self.late: dict = {}

    def add(self, m) -> bool:
        """FrameJoin.add: False when `m` is not of a per-frame topic."""
        if not self.join.add(m):
            return False
        block = self.join.finished(BLOCK)
        if block is not None:
            self.spool.add(block, len(block["index"]))
        return True

    def end(self) -> None:
        """The pass is over."""
        self.join.end()
        block = self.join.finished()
        if block is not None:
            self.spool.add(block, len(block["index"]))
        self.late = self.join.late

    def close(self) -> None:
        self.spool.close()

    def blocks(self) -> Iterator[dict]:
        """The rows in frame order, in blocks as spooled, the late messages laid over them
        (one empty block when there are no rows)."""
        given = False
        for block in self._laid():
            given = True
            yield block
        if not given:
            yield _Columns().take()

    def _laid(self) -> Iterator[dict]:
        late = self.late
        if not late:
            yield from self.spool.blocks()
            return
        spooled: set[int] = set()
        for block in self.spool.blocks():
            spooled.update(int(k) for k in block["index"])
        # a late message goes over its frame's row; a frame with none that it gives its CNN
        # output or preprocessing gets one, in frame order
        extra = {k: e for k, e in late.items() if k not in spooled and ("cnn" in e or "pre" in e)}
        for block in self.spool.blocks():
            if not len(block["index"]):
                continue
            mine = {int(k) for k in block["index"]}
            last = int(block["index"][-1])
            here = {k: e for k, e in late.items() if k in mine}
            here |= {k: extra.pop(k) for k in sorted(extra) if k <= last}
            rows = _Columns.of(block)
            lay_late(rows, here, append=True)
            yield rows.take()
        if extra:
            rows = _Columns()
            lay_late(rows, extra, append=True)
            yield rows.take()


@dataclass
class FrameSummary:
    """What the frames table's rows say as a whole, known before any row is written."""

    rows: int = 0
    stale: int = 0  # frames flagged stale_orientation
    earliest_ns: int | None = None  # the earliest frame time
    numeric: dict[str, bool] = field(  # feature field -> every value a number or None
        default_factory=lambda: dict.fromkeys(FEATURE_FIELDS, True)
    )


@dataclass
class TrialPass:
    """A recording read once (see the module's docstring): the spooled frame rows and
    IMU samples, and the small tables in memory (label changes in time order, events,
    gait events, as recorded)."""

    rec: object  # capture.recording.reader.Recording
    frames: FrameRows
    imu: Spool
    changes: list
    events: list
    gait: list
    imu_earliest_ns: int | None
    imu_fields: tuple[str, ...]

    TOPICS = (*FrameJoin.TOPICS, T.LABELS, T.IMU, T.EVENTS, T.GAIT, T.SIM_GAIT)

    @classmethod
    def read(
        cls, path: str | os.PathLike, spool: str | os.PathLike | None, imu_fields: tuple
    ) -> TrialPass:
        """The recording at `path` read once; the spool's files in folder `spool` (None:
        in memory); `imu_fields`: the IMU samples' fields kept (ImuColumns)."""
        rec = open_recording(path)
        messages = rec.messages([t for t in cls.TOPICS if t in rec.topics])
        return cls.gather(rec, messages, spool, imu_fields, FrameJoin())

    @classmethod
    def gather(cls, rec, messages, spool, imu_fields: tuple, join: FrameJoin) -> TrialPass:
        """read() from `messages` (of TOPICS, decoded), joined by `join`."""
        memory = spool is None
        frames = FrameRows(Spool(spool, memory=memory), join)
        imu_spool = Spool(spool, memory=memory)
        imu = ImuColumns(imu_fields)
        changes, events, gait = [], [], []
        earliest = None
        try:
            for m in messages:
                if frames.add(m):
                    continue
                if m.topic == T.LABELS:
                    changes.append(L.change_from_message(m.data))
                elif m.topic == T.IMU:
                    imu.add(m.data)
                    if len(imu) == BLOCK:
                        earliest = _earliest(earliest, imu.times())
                        imu_spool.add(imu, len(imu))
                        imu = ImuColumns(imu_fields)
                elif m.topic in (T.GAIT, T.SIM_GAIT):
                    gait.append(m.data)
                else:
                    events.append(m.data)
            frames.end()
            if len(imu):
                earliest = _earliest(earliest, imu.times())
                imu_spool.add(imu, len(imu))
        except BaseException:
            frames.close()
            imu_spool.close()
            raise
        return cls(
            rec,
            frames,
            imu_spool,
            L.in_time_order(changes),
            events,
            gait,
            earliest,
            imu_fields,
        )

    def __enter__(self) -> TrialPass:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.frames.close()
        self.imu.close()

    # ---- the frames' rows -----------------------------------------------------------------

    def frame_blocks(self, rows: int) -> Iterator[dict]:
        """The frames' rows (FrameJoin columns), the late messages laid over them, in frame
        order, in blocks of `rows` (the last may be shorter; one empty block when none)."""
        return _reblocked(self.frames.blocks(), rows, _Columns.NUMBERS, _Columns.LISTS)

    def frame_summary(self) -> FrameSummary:
        """Row count, stale frames, earliest time and the feature fields' kinds, over the
        rows frame_blocks gives (one read of the spool)."""
        out = FrameSummary()
        for block in self.frames.blocks():
            n = len(block["index"])
            if not n:
                continue
            out.rows += n
            out.stale += sum(1 for f in block["flag"] if f == "stale_orientation")
            out.earliest_ns = _earliest(out.earliest_ns, block["time_ns"])
            for name in FEATURE_FIELDS:
                if out.numeric[name]:
                    out.numeric[name] = all(_number_or_none(f.get(name)) for f in block["features"])
        return out

    # ---- the IMU samples ------------------------------------------------------------------

    def imu_blocks(self, rows: int) -> Iterator[ImuColumns]:
        """The IMU samples in file order, as ImuColumns of `rows` samples (the last may be
        shorter; one empty when none)."""
        gathered = ImuColumns(self.imu_fields)
        given = False
        for block in self.imu.blocks():
            while len(block):
                part, block = _split(block, rows - len(gathered))
                gathered.extend(part)
                if len(gathered) == rows:
                    yield gathered
                    gathered, given = ImuColumns(self.imu_fields), True
        if len(gathered) or not given:
            yield gathered


def _number_or_none(v) -> bool:
    return v is None or (isinstance(v, (int, float)) and not isinstance(v, bool))


def _earliest(earliest: int | None, times: np.ndarray) -> int | None:
    if not len(times):
        return earliest
    low = int(times.min())
    return low if earliest is None else min(earliest, low)


def _split(block: ImuColumns, first: int) -> tuple[ImuColumns, ImuColumns]:
    """The first `first` samples of `block`, and the rest."""
    n = len(block)
    return block.slice(0, min(first, n)), block.slice(min(first, n), n)


def _reblocked(blocks, rows: int, numbers, lists) -> Iterator[dict]:
    """Column blocks regrouped into blocks of exactly `rows` (the last may be shorter;
    one empty block when there are no rows at all)."""
    pending: list[dict] = []
    held = 0
    given = False
    for block in blocks:
        n = len(block["index"])
        start = 0
        while start < n:
            take = min(n - start, rows - held)
            pending.append({k: v[start : start + take] for k, v in block.items()})
            held += take
            start += take
            if held == rows:
                yield _joined(pending, numbers, lists)
                pending, held, given = [], 0, True
    if pending or not given:
        yield _joined(pending, numbers, lists) if pending else _Columns().take()


def _joined(parts: list[dict], numbers, lists) -> dict:
    if len(parts) == 1:
        return parts[0]
    out = {k: np.concatenate([p[k] for p in parts]) for k in numbers}
    for k in lists:
        out[k] = [v for p in parts for v in p[k]]
    return out
