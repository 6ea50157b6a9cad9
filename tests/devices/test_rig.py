"""The mock rig: the simulated walk's camera and IMU emulator in a child process.

The host side is what it would be with hardware: frames arriving, and the real Xbus driver
on the emulator's pseudo-terminal.
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from capture.config import Config
from capture.live.devices import close_devices, open_devices
from devices.errors import DeviceInitError
from devices.simulator.rig import RigCamera, RigImu
from tests.waiting import wait_for

pytestmark = pytest.mark.realtime


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead too
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture
def rig_devices():
    camera, imu = open_devices(Config())
    yield camera, imu
    close_devices(camera, imu)


def test_the_rigs_threads_run_at_real_time_priority_where_permitted(rig_devices):
    """Below the session's pipeline thread, above everything else: as hardware would."""
    camera, imu = rig_devices
    camera.start()
    wait_for(lambda: camera.recv(0.2) is not None)
    pid = camera.rig._child.pid
    policies = {os.sched_getscheduler(int(tid)) for tid in os.listdir(f"/proc/{pid}/task")}
    said = camera.rig.details["scheduling"]
    if os.geteuid() == 0:
        assert said == "SCHED_FIFO 5"
    assert policies == ({os.SCHED_FIFO} if said.startswith("SCHED_FIFO") else {os.SCHED_OTHER})
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # not this process


def test_real_time_mock_devices_run_in_the_rig(rig_devices):
    camera, imu = rig_devices
    assert isinstance(camera, RigCamera) and isinstance(imu, RigImu)
    assert camera.rig._child.pid != os.getpid()
    imu.start()
    camera.start()
    frames = [f for f in (camera.recv(1.0) for _ in range(10)) if f is not None]
    samples = [s for s in (imu.recv(0.5) for _ in range(50)) if s is not None]
    assert len(frames) == 10
    f = frames[-1]
    assert f.xyz.shape == (171, 224, 3) and f.xyz.dtype == np.float32
    assert f.confidence.shape == (171, 224) and f.gray.shape == (171, 224)
    assert np.count_nonzero(f.confidence) > 1000  # real depth, not zeros
    assert f.truth["mode"] in ("LG", "US", "DS", "UR", "DR")
    assert [g.index for g in frames] == sorted(g.index for g in frames)
    assert f.geometry == camera.geometry
    assert f.device_time_ns <= f.host_time_ns  # one clock on both sides of the pipe
    # the IMU is the real driver on the rig's pty; the rig knows when samples were taken
    assert len(samples) == 50 and samples[-1].quaternion is not None
    errors = [abs(s.time_ns - imu.true_time_ns(s.sample_time_fine)) for s in samples[-20:]]
    assert np.median(errors) < 5e6


def test_the_rig_ends_with_its_devices(rig_devices):
    camera, imu = rig_devices
    process = camera.rig._child.process
    close_devices(camera)
    assert process.poll() is None  # the IMU still needs its emulator
    close_devices(imu)
    assert process.poll() is not None


@pytest.mark.subprocess
def test_the_rig_ends_when_the_host_dies(tmp_path):
    script = tmp_path / "host.py"
    script.write_text(
        "import sys, time\n"
        "from capture.config import Config\n"
        "from capture.live.devices import open_devices\n"
        "camera, imu = open_devices(Config())\n"
        "print(camera.rig._child.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    host = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        text=True,  # PYTHONPATH (conftest): this checkout's walkcap, not an installed one
    )
    try:
        child = int(host.stdout.readline())
        assert alive(child)
        host.send_signal(signal.SIGKILL)
        host.wait()
        wait_for(lambda: not alive(child), 5.0, what="the rig's end with its host")
    finally:
        host.kill()


def test_faults_cross_to_the_rig(rig_devices):
    camera, imu = rig_devices
    imu.start()
    camera.start()
    assert camera.recv(2.0) is not None
    camera.inject("stall", seconds=1.5)
    time.sleep(0.2)
    while camera.recv(0) is not None:
        pass
    assert camera.recv(1.0) is None  # nothing while stalled
    assert camera.recv(2.0) is not None  # and frames again after
    imu.inject("disconnect")
    wait_for(lambda: imu.status().state == "lost", 2.0)
    imu.inject("reconnect")
    wait_for(lambda: imu.status().state == "ok", 5.0)
    with pytest.raises(DeviceInitError, match="unknown camera fault"):
        camera.inject("melt")


def test_a_rig_that_cannot_start_is_one_clear_error():
    config = Config()
    config.imu.rate_hz = 5000  # beyond the emulator
    with pytest.raises(DeviceInitError, match="mock devices failed to start: .*rate 5000"):
        open_devices(config)


def test_a_fast_mock_imu_needs_a_model_and_line_that_carry_it():
    config = Config()
    config.imu.rate_hz = 400  # 115200 baud carries about 157 messages/s; a 1-series 100 Hz
    config.imu.emulate, config.imu.baudrate = "MTi-630", 921600
    camera, imu = open_devices(config)
    try:
        imu.start()
        # A second of samples: a line too slow for them would overflow the device's buffer
        # within a quarter of that, losing packets.
        samples = [imu.recv(2.0) for _ in range(400)]
        assert all(s is not None for s in samples)
        packets = np.diff([s.packet_counter for s in samples]) % 2**16
        ticks = np.diff([s.sample_time_fine for s in samples]) % 2**32
        assert set(packets) == {1} and set(ticks) == {25}  # 400 Hz on the 10 kHz clock
        assert imu.missing_packets == 0
    finally:
        close_devices(camera, imu)


def test_frames_the_renderer_skipped_are_told_apart_from_frames_lost(rig_devices):
    """Both are missing frames (errors); the skipped ones are the simulator's own doing
    (its renderer fell behind on a busy machine), which `walkcap bench --soak` shows apart."""
    from capture.bench import renderer_skipped

    camera, _ = rig_devices
    camera.on_event("gap", "4 frames skipped: the simulator is too slow", {"skipped": 4})
    camera.on_event("drop", "2 frames dropped", {"dropped": 2})
    status = camera.status()
    assert status.errors == 6
    assert renderer_skipped(status) == 4
    assert status.dropped + status.errors - renderer_skipped(status) == 2
