"""Numbers that change with every snapshot (rates, sizes) are redrawn a few times a second;
a change of state is redrawn at once. Terminal redraws cost the capture threads CPU."""

from __future__ import annotations

import time

IMAGE_HZ = 10.0  # the image and the profile: nobody reads braille faster, and they cost most


class Pacer:
    def __init__(self, hz: float = 2.0, clock=time.monotonic) -> None:
        self.period = 1.0 / hz
        self._clock = clock
        self._last = float("-inf")

    def due(self, urgent: bool = False) -> bool:
        """True when a redraw may happen now (always when `urgent`)."""
        now = self._clock()
        if urgent or now - self._last >= self.period:
            self._last = now
            return True
        return False
