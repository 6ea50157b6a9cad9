"""What every streaming fusion method shares (inference.fusion): the output record, the
protocol, the frame's probability row, voting and the per-sequence bookkeeping."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from inference.errors import InferenceError
from inference.fusion_design import N_MODES

_INF = float("inf")


@dataclass(slots=True)
class FusionOutput:
    """What one push (or flush) made known.

    `frame`/`decision`: the decision of the method's first stage (argmax, HMM smooth state,
    filter, smoother) and the frame it refers to; `push` returns None until the first
    decision exists, so these are set in every pushed output (None only in flush outputs
    that carry nothing but votes).
    `probabilities` (`posterior` as an array): the method's distribution for
    `posterior_frame`. For the HMM that is the smoothed p(s_t) of the newest frame
    (Algorithm 1's second output), one frame after `frame`; for the others, `frame`.
    `voted`/`voted_frame`: the vote, for methods with voting, once its window is complete.
    """

    frame: int | None
    decision: int | None
    posterior_frame: int | None = None
    probabilities: tuple[float, ...] | None = None
    voted: int | None = None
    voted_frame: int | None = None

    @property
    def posterior(self) -> np.ndarray | None:
        # Built on demand: an array per frame would cost more than the fusion update.
        return None if self.probabilities is None else np.array(self.probabilities)


class Fusion(Protocol):
    """A streaming fusion method (see the module docstring)."""

    method: str
    delay_frames: int  # frames between a frame's arrival and its final decision
    votes: bool  # the final decision is `voted` (else `decision`)

    def push(self, probabilities: np.ndarray | Sequence[float]) -> FusionOutput | None: ...

    def flush(self) -> list[FusionOutput]: ...

    def reset(self) -> None: ...


# ---------------------------------------------------------------------------------------
# streaming methods


def probability_row(probabilities) -> list[float]:
    """The frame's probabilities as 5 Python floats (the fast path), checked cheaply."""
    e = (
        probabilities.tolist()
        if isinstance(probabilities, np.ndarray)
        else [float(x) for x in probabilities]
    )
    if len(e) != N_MODES:
        raise InferenceError(f"fusion: expected {N_MODES} probabilities, got {len(e)}")
    total = e[0] + e[1] + e[2] + e[3] + e[4]
    if not 0.0 < total < _INF or min(e) < 0.0:
        raise InferenceError(f"fusion: not a probability vector: {e}")
    return e


def majority(decisions: Iterable[int]) -> int:
    counts = [0] * N_MODES
    for d in decisions:
        counts[d] += 1
    return counts.index(max(counts))  # ties: smallest index, as MATLAB's mode()


class Voter:
    """Voting: the mode of decisions over frames f-l_v..f+l_v, streamed.

    Feed decisions in frame order; the vote for frame f is returned with decision f+l_v.
    """

    def __init__(self, vote_delay: int):
        if vote_delay < 0:
            raise InferenceError(f"vote delay must be >= 0, got {vote_delay}")
        self.vote_delay = vote_delay
        self._recent: deque[int] = deque(maxlen=2 * vote_delay + 1)
        self._next = 0  # the frame of the next decision
        self._unvoted = 0  # the first frame without a vote

    def reset(self) -> None:
        self._recent.clear()
        self._next = self._unvoted = 0

    def push(self, frame: int, decision: int) -> tuple[int, int] | None:
        """(voted frame, vote) once frame - l_v has its full window, else None."""
        if frame != self._next:
            raise InferenceError(f"voting: expected frame {self._next}, got {frame}")
        self._next += 1
        self._recent.append(decision)
        voted_frame = frame - self.vote_delay
        if voted_frame < 0:
            return None
        self._unvoted = voted_frame + 1
        # The deque holds frames max(0, f-l_v)..f+l_v: the window, cut at the start.
        return voted_frame, majority(self._recent)

    def flush(self) -> list[tuple[int, int]]:
        """Votes of the frames still waiting, over windows cut at the end of the sequence."""
        lv, n = self.vote_delay, self._next
        recent = list(self._recent)
        first = n - len(recent)  # the frame of recent[0]
        votes = [(f, majority(recent[max(0, f - lv) - first :])) for f in range(self._unvoted, n)]
        self._unvoted = n
        return votes


class Stream:
    """Frame counting, voting and the end-of-sequence flag shared by every method."""

    method = "fusion"  # make_fusion names each object after its row of METHOD_TABLE
    delay_frames: int

    def __init__(self, vote_delay: int | None):
        self.votes = vote_delay is not None
        self._voter = Voter(vote_delay) if vote_delay is not None else None
        self._frame = 0  # frames pushed so far
        self._flushed = False

    def reset(self) -> None:
        self._frame = 0
        self._flushed = False
        if self._voter is not None:
            self._voter.reset()
        self._reset_state()

    def _reset_state(self) -> None:
        raise NotImplementedError

    def _check_open(self) -> None:
        if self._flushed:
            raise InferenceError(f"{self.method}: the sequence was flushed; reset() first")

    def _voted(self, out: FusionOutput) -> FusionOutput:
        """`out` with the vote its decision completes, when voting and one is due."""
        if self._voter is not None:
            vote = self._voter.push(out.frame, out.decision)
            if vote is not None:
                out.voted_frame, out.voted = vote
        return out

    def _vote_outputs(self) -> list[FusionOutput]:
        if self._voter is None:
            return []
        return [FusionOutput(None, None, voted=v, voted_frame=f) for f, v in self._voter.flush()]
