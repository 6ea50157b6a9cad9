"""A camera backend driven by the test, and a blank frame to feed it."""

import numpy as np

from devices.camera import Camera
from devices.clock import now_ns
from devices.frames import DepthFrame


def blank_frame(index: int) -> DepthFrame:
    return DepthFrame(
        index,
        now_ns(),
        now_ns(),
        np.zeros((2, 2, 3), np.float32),
        np.zeros((2, 2), np.uint8),
        np.zeros((2, 2), np.uint16),
    )


class ScriptedCamera(Camera):
    """A backend whose producer is the test: it records the hooks called."""

    backend = "scripted"

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        self.calls = []

    def _open(self):
        self.calls.append("open")

    def _start(self):
        self.calls.append("start")

    def _stop(self):
        self.calls.append("stop")

    def _close(self):
        self.calls.append("close")
