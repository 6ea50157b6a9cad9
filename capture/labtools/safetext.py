"""Text from other programs (a remote-control client, a Foxglove client) on its way to the
operator's terminal, a log or an event: escaped, cut short, and counted when it repeats.

A client's bytes never reach a terminal as they are: ESC, BEL and the other control and
format characters (a bidi override too) become visible escapes such as \\x1b, so a client
cannot retitle, clear or recolour the operator's screen. A flood of the same complaint is
counted rather than printed: the first few of a kind, then one at each power of ten with
its count.
"""

from __future__ import annotations

import re
import threading

TEXT_LIMIT = 200  # characters of client text kept in one line
KINDS = 256  # kinds counted apart; further kinds share one count


def escape(text: str, limit: int = TEXT_LIMIT) -> str:
    """`text` fit for a terminal: every non-printable character as an escape, at most
    `limit` characters of it (the length said when cut)."""
    shown = "".join(
        ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii")
        for ch in text[:limit]
    )
    return shown if len(text) <= limit else f"{shown}... ({len(text)} characters)"


def kind_of(text: str, length: int = 32) -> str:
    """What a message says with its numbers (ports, ids, counts) left out: repeats of one
    complaint about different clients or channels are one kind."""
    return re.sub(r"[0-9]+", "#", text[: length * 2])[:length]


class Repeats:
    """Counts messages by kind; `check` says whether this one is shown.

    The first `burst` of a kind are shown, then the 10th, 100th, 1,000th ... of it, each
    with its count; no clock involved, so a flood prints a handful of lines whatever its
    pace.
    """

    def __init__(self, burst: int = 3) -> None:
        self.burst = burst
        self.counts: dict[str, int] = {}
        self.total = 0
        self.shown = 0
        self._lock = threading.Lock()

    def check(self, kind: str) -> tuple[bool, int]:
        """(show it, how many of its kind so far, this one included)."""
        with self._lock:
            if kind not in self.counts and len(self.counts) >= KINDS:
                kind = "(other)"
            n = self.counts.get(kind, 0) + 1
            self.counts[kind] = n
            self.total += 1
            show = n <= self.burst or _power_of_ten(n)
            self.shown += show
            return show, n

    @property
    def held_back(self) -> int:
        return self.total - self.shown


def _power_of_ten(n: int) -> bool:
    while n % 10 == 0:
        n //= 10
    return n == 1
