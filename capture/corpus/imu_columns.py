"""An export table's IMU samples as numpy columns, gathered as they are read
(capture.corpus.export)."""

from __future__ import annotations

import numpy as np


class ImuColumns:
    """The IMU samples' `fields` (integers, and the vectors of _VECTORS), gathered into
    numpy columns as they are read: a long trial's samples are many, and a tuple of
    lists a sample costs ten times the memory."""

    _VECTORS = {"quaternion": 4, "acceleration": 3, "rate_of_turn": 3}

    def __init__(self, fields: tuple[str, ...]) -> None:
        self.n = 0
        self.ints = [k for k in fields if k not in self._VECTORS]
        self.integers = np.zeros((1024, len(self.ints)), dtype=np.int64)
        self.known = np.zeros((1024, len(self.ints)), dtype=bool)  # False: the value is None
        self.at: dict[str, slice] = {}  # vector field -> its columns in `vectors`
        start = 0
        for k in (k for k in fields if k in self._VECTORS):
            self.at[k] = slice(start, start + self._VECTORS[k])
            start += self._VECTORS[k]
        self.vectors = np.full((1024, sum(self._VECTORS.values())), np.nan)

    def __len__(self) -> int:
        return self.n

    def add(self, s: dict) -> None:
        if self.n == len(self.integers):
            more = max(self.n, 1024)
            self.integers = np.concatenate(
                [self.integers, np.zeros((more, len(self.ints)), np.int64)]
            )
            self.known = np.concatenate([self.known, np.zeros((more, len(self.ints)), bool)])
            self.vectors = np.concatenate(
                [self.vectors, np.full((more, self.vectors.shape[1]), np.nan)]
            )
        k = self.n
        for j, name in enumerate(self.ints):
            v = s.get(name)
            if v is not None:
                self.integers[k, j] = v
                self.known[k, j] = True
        for name, columns in self.at.items():
            v = s.get(name)
            if v is not None:
                self.vectors[k, columns] = [np.nan if x is None else x for x in v]
        self.n += 1

    def slice(self, start: int, stop: int) -> ImuColumns:
        """Samples start..stop-1, as columns of their own."""
        out = ImuColumns.__new__(ImuColumns)
        out.n, out.ints, out.at = stop - start, self.ints, self.at
        out.integers = self.integers[start:stop].copy()
        out.known = self.known[start:stop].copy()
        out.vectors = self.vectors[start:stop].copy()
        return out

    def extend(self, other: ImuColumns) -> None:
        """`other`'s samples (the same fields) after these."""
        n = self.n
        self.integers = np.concatenate([self.integers[:n], other.integers[: other.n]])
        self.known = np.concatenate([self.known[:n], other.known[: other.n]])
        self.vectors = np.concatenate([self.vectors[:n], other.vectors[: other.n]])
        self.n = n + other.n

    def ints_of(self, name: str):
        """An integer field as pandas' nullable Int64 (None: a gap)."""
        import pandas as pd  # export checks that it is there

        j = self.ints.index(name)
        values, known = self.integers[: self.n, j], self.known[: self.n, j]
        return pd.arrays.IntegerArray(values.copy(), ~known)

    def times(self) -> np.ndarray:
        """Each sample's time: its sample time, else its arrival."""
        t, host = self.ints.index("time_ns"), self.ints.index("host_time_ns")
        known = self.known[: self.n, t]
        return np.where(known, self.integers[: self.n, t], self.integers[: self.n, host])

    def vector(self, name: str) -> np.ndarray:
        return self.vectors[: self.n, self.at[name]]
