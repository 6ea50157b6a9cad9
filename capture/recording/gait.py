"""A recording's gait events as a table: the detector's (/gait) and the simulator's (/sim/gait).

    gait = read_gait("S01_indoor_t01.mcap", source="simulator")
    gait.heel_contacts().time_ns        # int64, session clock
    gait.events()                       # [GaitEvent, ...] in time order

Both topics carry one GaitEvent a message (devices.frames); the table holds them in time
order, `mode` "" where the terrain under the foot is not known (the detector's events).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture.recording import topics as T
from capture.recording.reader import Recording, open_recording
from devices.frames import GAIT_SOURCES, MODES, GaitEvent

SOURCE_TOPICS = {"imu": T.GAIT, "simulator": T.SIM_GAIT}


@dataclass(frozen=True)
class GaitTable:
    """Gait events, one a row, in time order (ties: the order they were recorded)."""

    time_ns: np.ndarray  # (N,) int64, session clock
    event: np.ndarray  # (N,) str: "heel_contact" or "toe_off"
    source: np.ndarray  # (N,) str: "imu" or "simulator"
    mode: np.ndarray  # (N,) str: the MODES name under the foot, "" where not known

    def __len__(self) -> int:
        return len(self.time_ns)

    @property
    def mode_index(self) -> np.ndarray:
        """(N,) int64: MODES index of `mode`, -1 where not known."""
        lookup = {m: i for i, m in enumerate(MODES)}
        return np.array([lookup.get(m, -1) for m in self.mode], dtype=np.int64)

    def select(self, rows) -> GaitTable:
        """The rows a boolean mask or an index array picks."""
        return GaitTable(self.time_ns[rows], self.event[rows], self.source[rows], self.mode[rows])

    def of(self, *, event: str | None = None, source: str | None = None) -> GaitTable:
        """The rows of one event kind and/or one source."""
        keep = np.ones(len(self), dtype=bool)
        if event is not None:
            keep &= self.event == event
        if source is not None:
            keep &= self.source == source
        return self.select(keep)

    def heel_contacts(self) -> GaitTable:
        return self.of(event="heel_contact")

    def toe_offs(self) -> GaitTable:
        return self.of(event="toe_off")

    def events(self) -> list[GaitEvent]:
        return [
            GaitEvent(int(t), str(e), str(s), str(m) or None)
            for t, e, s, m in zip(self.time_ns, self.event, self.source, self.mode, strict=True)
        ]


def gait_table(events) -> GaitTable:
    """A GaitTable of GaitEvents, sorted by time (stable)."""
    events = sorted(events, key=lambda e: e.time_ns)
    return GaitTable(
        np.array([e.time_ns for e in events], dtype=np.int64),
        np.array([e.event for e in events], dtype=np.str_).astype("U12"),
        np.array([e.source for e in events], dtype=np.str_).astype("U9"),
        np.array([e.mode or "" for e in events], dtype=np.str_).astype("U2"),
    )


def read_gait(recording, source: str | None = None) -> GaitTable:
    """The gait events of a recording (a path or an open Recording): the detector's
    (`source="imu"`, /gait), the simulator's (`"simulator"`, /sim/gait) or both (None)."""
    if source is not None and source not in GAIT_SOURCES:
        raise ValueError(f"gait source {source!r}: expected one of {', '.join(GAIT_SOURCES)}")
    rec = recording if isinstance(recording, Recording) else open_recording(os.fspath(recording))
    sources = GAIT_SOURCES if source is None else (source,)
    wanted = [SOURCE_TOPICS[s] for s in sources if SOURCE_TOPICS[s] in rec.topics]
    events = [T.gait_from_message(m.data) for m in rec.messages(wanted)] if wanted else []
    return gait_table(events)
