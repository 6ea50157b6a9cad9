"""The Recorder's queue: one record per write_* call, held for the writer thread.

Callers put references (no copies, no encoding) and return at once. The queue keeps raw
items (depth, IMU samples, events, truth, messages) apart from derived ones (clouds,
images, inference, features): when the writer falls behind, derived items are shed first
so raw data keeps its place (capture.recording.writer).
"""

from __future__ import annotations

import collections
import queue
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

STOP = object()  # the writer's last item: finish the file

# ---- the items: one record per write_* call, one encoder per record (ChunkWriter._ENCODERS)
# Slotted dataclasses, not frozen: one allocation per item, several times cheaper to build
# than a frozen one on the callers' 45 fps path. Nothing modifies an item once queued.


class QueuedItem:
    """One write_* call's data on its way to the writer thread."""

    __slots__ = ()
    kind: ClassVar[str]  # what its drops are counted as (RecorderStats.dropped_by_kind, /events)
    # Computed from the raw data (clouds, images, inference, features): shed first when the
    # writer falls behind, so raw depth, IMU samples and events keep their place.
    derived: ClassVar[bool] = False
    # A depth frame weighs megabytes; IMU samples, events and messages bytes: the queue
    # bounds the heavy ones by its size and holds LIGHT_FACTOR times as many light ones,
    # so the backlog of a host stall (5 s of IMU samples at once) finds room.
    heavy: ClassVar[bool] = False


@dataclass(slots=True)
class QueuedFrame(QueuedItem):
    kind: ClassVar[str] = "frame"
    heavy: ClassVar[bool] = True
    frame: Any  # a DepthFrame
    time_ns: int | None  # publish time; None: the frame's device time


@dataclass(slots=True)
class QueuedImuSample(QueuedItem):
    kind: ClassVar[str] = "imu"
    sample: Any  # an ImuSample


@dataclass(slots=True)
class FrameItem(QueuedItem):
    """An item about one depth frame: its index and time on the session clock."""

    index: int
    time_ns: int


@dataclass(slots=True)
class LoggedFrameItem(FrameItem):
    """A frame's item that carries its own MCAP log time (when it was computed); the items
    of the frame without one take it from these (ChunkWriter._log_time)."""

    log_time: int


@dataclass(slots=True)
class QueuedProcessing(LoggedFrameItem):
    kind: ClassVar[str] = "processed"
    derived: ClassVar[bool] = True
    cloud: np.ndarray
    image: np.ndarray
    quaternion: Any  # None: orientation unknown
    flag: str


@dataclass(slots=True)
class QueuedInference(LoggedFrameItem):
    kind: ClassVar[str] = "inference"
    derived: ClassVar[bool] = True
    probs: Any
    fused: dict | None


@dataclass(slots=True)
class QueuedFeatures(FrameItem):
    kind: ClassVar[str] = "features"
    derived: ClassVar[bool] = True
    features: dict


@dataclass(slots=True)
class QueuedTruth(FrameItem):
    kind: ClassVar[str] = "truth"
    truth: dict


@dataclass(slots=True)
class QueuedGait(QueuedItem):
    # Raw, not derived, though the detector computes it: two a second weigh nothing, and the
    # steps the operator saw counted are the ones the file keeps.
    kind: ClassVar[str] = "gait"
    event: Any  # a devices.frames.GaitEvent
    log_time: int | None


@dataclass(slots=True)
class QueuedEncodedFrame(LoggedFrameItem):
    """A frame's messages encoded in another process (replay's reader)."""

    kind: ClassVar[str] = "encoded"
    heavy: ClassVar[bool] = True
    messages: list  # of capture.recording.encode.Encoded


@dataclass(slots=True)
class QueuedRecorded(QueuedItem):
    """Messages of another recording copied as they are (replay's IMU samples)."""

    kind: ClassVar[str] = "recorded"
    messages: list  # of capture.recording.encode.Encoded


@dataclass(slots=True)
class QueuedMessage(QueuedItem):
    """A JSON message on a topic declared with Recorder.declare_topic (an LSL stream)."""

    kind: ClassVar[str] = "message"
    topic: str
    time_ns: int
    log_time: int
    message: dict


@dataclass(slots=True)
class QueuedDeviceEvent(QueuedItem):
    kind: ClassVar[str] = "event"
    event: Any  # a DeviceEvent or a dict


# Raw items queued beyond this share of their room (frames: seconds of them at 45 fps): the
# writer is behind, derived ones are shed and raw ones go first.
SHED_BACKLOG = 0.25
LIGHT_FACTOR = 8  # light raw items (IMU, events, messages, truth) held: this x the size


class WriteQueue:
    """The writer's queue in two parts: raw items (depth, IMU, events, truth, messages)
    and derived ones (clouds, images, inference, features), taken in the order they came.
    When the writer falls behind (raw items pile up), raw ones go first and derived ones
    are shed, the queued ones too, so raw data is dropped only when its own part is full
    (the disk itself cannot keep up)."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._raw: collections.deque = collections.deque()
        self._heavy = 0  # heavy items among the raw ones
        self._derived: collections.deque = collections.deque()
        self._derived_max = max(1, maxsize // 2)
        self._cond = threading.Condition()
        self._count = 0  # items put: each queued one carries its number, the order they came
        self.shed: collections.Counter = collections.Counter()  # derived items shed, by kind

    def qsize(self) -> int:
        return len(self._raw) + len(self._derived)

    def put_nowait(self, item) -> None:
        self.put(item, block=False)

    def put(self, item, block: bool = True, timeout: float | None = None) -> None:
        """Queue an item; queue.Full when a raw one finds no room. Without `block` a
        derived item that finds no room, or the writer behind on raw data, is shed."""
        derived = getattr(item, "derived", False)
        with self._cond:
            while True:
                if derived:
                    behind = self._behind() and not block
                    if not behind and len(self._derived) < self._derived_max:
                        self._derived.append((self._count, item))
                        break
                    if not block:
                        self.shed[item.kind] += 1
                        return
                elif item is STOP or self._room(item):
                    self._raw.append((self._count, item))
                    self._heavy += getattr(item, "heavy", False)
                    if self._behind() and not block:
                        self._shed_queued()
                    break
                if not block or not self._cond.wait(timeout):
                    raise queue.Full
            self._count += 1
            self._cond.notify_all()

    def _behind(self) -> bool:
        light = len(self._raw) - self._heavy
        return (
            self._heavy > SHED_BACKLOG * self.maxsize
            or light > SHED_BACKLOG * LIGHT_FACTOR * self.maxsize
        )

    def _room(self, item) -> bool:
        if item.heavy:
            return self._heavy < self.maxsize
        return len(self._raw) - self._heavy < LIGHT_FACTOR * self.maxsize

    def _shed_queued(self) -> None:
        while self._derived:
            self.shed[self._derived.popleft()[1].kind] += 1

    def get(self, timeout: float | None = None):
        """The oldest item; raw ones first while they pile up; the stop mark comes last."""
        with self._cond:
            while True:
                raw, derived = self._raw, self._derived
                if raw and (
                    not derived
                    or (raw[0][1] is not STOP and self._behind())
                    or (raw[0][1] is not STOP and raw[0][0] < derived[0][0])
                ):
                    item = raw.popleft()[1]
                    self._heavy -= getattr(item, "heavy", False)
                    break
                if derived:
                    item = derived.popleft()[1]
                    break
                if not self._cond.wait(timeout):
                    raise queue.Empty
            self._cond.notify_all()
            return item

    def get_nowait(self):
        with self._cond:
            if not self._raw and not self._derived:
                raise queue.Empty
        return self.get(0)
