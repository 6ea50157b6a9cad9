"""The mock camera: the terrain-walk simulator behind the camera interface.

It renders on its own thread. Frame k shows the walk at t = k / fps seconds;
`device_time_ns = start_time_ns + t` (session clock), `host_time_ns` is when it was
delivered. With `realtime` it paces frames at the configured fps (a frame late by a
little is sent late; CATCH_UP_FRAMES late, frames are skipped, counted and reported as a
"gap"); otherwise it renders as fast as the consumer takes
frames, never dropping one. At the end of the course it stops (state "stopped", event
"end_of_course"), or starts the course again with `loop=True`. Each frame delivered carries
in `truth["gait"]` the walk's gait events since the frame delivered before (none standing).

The IMU emulator must see the same walk on the same time base: give it
`camera.orientation_at` (or `camera.simulator.thigh_quaternion` without looping), with t in
seconds since `camera.start_time_ns`. Set `start_time_ns` before `start()` to share a
start time chosen elsewhere; otherwise `start()` sets it.

`clock` (session clock, ns) and `sleep` (seconds; True when the camera is stopped
meanwhile) pace the frames: a test passes a fake pair and steps through time exactly.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from devices import clock
from devices.base import Producer
from devices.camera import Camera
from devices.clock import now_ns
from devices.frames import CameraGeometry
from devices.simulator.simulator import Simulator

log = logging.getLogger(__name__)

# A frame rendered late (the host busy a moment) is still sent, stamped with its own time,
# and the renderer catches up (a frame renders in a fraction of the frame period); only
# this far behind are frames skipped, as a camera's own buffer would overflow.
CATCH_UP_FRAMES = 3


class MockCamera(Camera):
    backend = "mock"

    def __init__(
        self,
        config=None,
        simulator_config=None,
        *,
        simulator: Simulator | None = None,
        loop: bool = False,
        realtime: bool | None = None,
        geometry: CameraGeometry | None = None,
        clock: Callable[[], int] = now_ns,
        sleep: Callable[[float], bool] | None = None,
    ) -> None:
        super().__init__(config, geometry=geometry, clock=clock)
        if simulator is None:
            if simulator_config is None:
                from devices.config import SimulatorConfig

                simulator_config = SimulatorConfig()
            # One thread per frame's ray cast: the session's pipeline keeps the other core,
            # as beside a real camera (all cores only cut the cast's wall time).
            simulator = Simulator.from_config(
                simulator_config,
                self.geometry,
                cast_threads=1,
                fps=float(getattr(config, "fps", 15.0)),
            )
            if realtime is None:
                realtime = simulator_config.realtime
        self.simulator = simulator
        self.geometry = simulator.geometry
        self.loop = loop or bool(getattr(simulator_config, "loop", False))
        self.stand = bool(getattr(simulator_config, "stand", False))
        self.realtime = True if realtime is None else realtime
        self.start_time_ns: int | None = None
        self._producer = Producer("walkcap-mock-camera", self._run)
        self._halt = self._producer.halt
        self._clock = clock
        self._sleep = sleep or self._halt.wait
        self._stall_until_ns = 0
        self._resume_k: int | None = None
        self._gait_walk_s: float | None = None  # walk time of the last frame's gait truth
        course = simulator.course
        self.details = {
            "course": course.preset,
            "seed": course.seed,
            "modes": " ".join(course.modes),
            "duration_s": round(simulator.duration_s, 2),
            "loop": self.loop,
            "realtime": self.realtime,
        }

    @classmethod
    def from_config(cls, camera_config, simulator_config=None, **kw) -> MockCamera:
        return cls(camera_config, simulator_config, **kw)

    def walk_time(self, t_s: float) -> float:
        """Seconds since start -> time in the walk (wraps when looping; 0 when standing)."""
        if self.stand:
            return 0.0  # the start of the course: level ground, thigh at its mean angle
        duration = self.simulator.duration_s
        return t_s % duration if self.loop and t_s >= 0 else t_s

    def inject(self, fault: str, seconds: float = 2.0) -> None:
        """A fault for tests and drills: "stall" delivers no frame for `seconds`."""
        if fault != "stall":
            raise ValueError(f"unknown camera fault {fault!r} (known: stall)")
        self._stall_until_ns = self._clock() + clock.to_ns(seconds)

    def orientation_at(self, t_s: float) -> np.ndarray:
        """The thigh orientation t_s seconds after start_time_ns (what the IMU should see)."""
        return self.simulator.thigh_quaternion(self.walk_time(t_s))

    def _open(self) -> None:
        # The first cast commits the scene's acceleration structure: here, while the device
        # opens, not in the first frame of a real-time stream.
        self.simulator.truth_at(0.0)

    def _start(self) -> None:
        if self.start_time_ns is None:
            self.start_time_ns = self._clock()
            self._gait_walk_s = None  # a new walk
        self._producer.start()

    def _stop(self) -> None:
        self._producer.stop()
        self.start_time_ns = None  # a new start() begins a new walk

    def _restart(self) -> None:
        """The producer restarted where the walk is now (the walk goes on while silent)."""
        self._producer.stop()
        if self.start_time_ns is None:
            self._start()
            return
        self._resume_k = max(
            0, int(clock.seconds(self._clock() - self.start_time_ns) * self.config.fps)
        )
        self._producer.start()

    def _run(self) -> None:
        try:
            self._produce()
        except Exception as e:  # a bug in the simulator must show, not hang the session
            log.exception("mock camera")
            self._fail(f"simulator failed: {type(e).__name__}: {e}")

    def _produce(self) -> None:
        period = 1.0 / self.config.fps
        start = self.start_time_ns
        k = 0
        if self._resume_k is not None:  # reopened: the frame due now, the walk went on
            k, self._resume_k = self._resume_k, None
        while not self._halt.is_set():
            t = k * period
            if t > self.simulator.duration_s and not self.loop:
                self._finish("end_of_course", f"end of the course after {k} frames")
                return
            if self.realtime:
                wait = clock.seconds(start + t * 1e9 - self._clock())
                if wait > 0 and self._sleep(wait):
                    return
                behind = int(-wait / period)
                if behind >= CATCH_UP_FRAMES:  # too late: skip to the current frame
                    self._count_error(behind)
                    self._event(
                        "gap", f"{behind} frames skipped: the simulator is too slow", skipped=behind
                    )
                    k += behind
                    continue
            else:
                while len(self._buffer) >= self._buffer_size and not self._halt.is_set():
                    time.sleep(0.002)  # as fast as the consumer takes frames, losing none
            walk_s = self.walk_time(t)
            frame = self.simulator.render(walk_s, index=k)
            frame.device_time_ns = start + clock.to_ns(t)
            frame.host_time_ns = self._clock()
            if frame.host_time_ns >= self._stall_until_ns:  # a stalled camera sends nothing
                self._add_gait_truth(frame, walk_s)
                self._deliver(frame)
            k += 1

    def _add_gait_truth(self, frame, walk_s: float) -> None:
        """The walk's gait events since the last frame delivered (a skipped or stalled
        frame's go with the next one), on the frame's device clock."""
        if self.stand:
            return
        since = -1.0 if self._gait_walk_s is None else self._gait_walk_s  # the walk starts at 0
        sim, t_ns = self.simulator, frame.device_time_ns
        if walk_s >= since:
            events = sim.gait_truth(since, walk_s, t_ns)
        else:  # the course began again: the end of the last walk, then the new one
            wrap_ns = t_ns - clock.to_ns(walk_s)
            events = sim.gait_truth(since, sim.duration_s, wrap_ns)
            events += sim.gait_truth(-1.0, walk_s, t_ns)
        self._gait_walk_s = walk_s
        if events and frame.truth is not None:
            frame.truth["gait"] = events

    @property
    def _buffer_size(self) -> int:
        return max(1, self.config.buffer_frames)
