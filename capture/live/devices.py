"""The session's two devices: opened together (one walk for a mock pair), closed together,
and described for a recording's "devices" metadata record."""

from __future__ import annotations

import logging

from capture import config as config_mod
from capture.recording.metadata import devices_record
from devices import clock
from devices.clock import now_ns

log = logging.getLogger(__name__)


def stream_periods(config: config_mod.Config) -> dict[str, float]:
    """The configured period of each sensor stream (what a gap is measured against)."""
    return {"camera": 1.0 / config.camera.fps, "imu": 1.0 / config.imu.rate_hz}


def open_devices(config: config_mod.Config, camera=None, imu=None):
    """The configured camera and IMU, opened and configured, not yet started.

    On a mock walk the IMU emulator feels the same thigh the camera rides on: both count
    walk time from one instant, as a real sensor pair on one leg would. In real time (the
    default) both run in a child process, the mock rig, as hardware runs outside the host.
    """
    from devices.camera import open_camera
    from devices.imu import open_imu

    sim = config.simulator
    if (
        camera is None
        and imu is None
        and config.camera.backend == "mock"
        and config.imu.backend == "mock"
        and sim.realtime
        and sim.process
    ):
        return _open_rig(config)
    if camera is None:
        camera = open_camera(config.camera, config.simulator)
    try:
        camera.open()
        if imu is None:
            if hasattr(camera, "orientation_at"):
                camera.start_time_ns = now_ns()
                offset = {"s": 0.0}  # emulator start - camera start, known once it runs
                imu = open_imu(
                    config.imu, orientation_at=lambda t: camera.orientation_at(t + offset["s"])
                )
                emulator = getattr(imu, "emulator", None)
                if emulator is not None and emulator.start_time_ns is not None:
                    offset["s"] = clock.seconds(emulator.start_time_ns - camera.start_time_ns)
            else:
                imu = open_imu(config.imu)
        imu.open()
    except BaseException:
        close_devices(imu, camera)
        raise
    return camera, imu


def _open_rig(config: config_mod.Config):
    from devices.simulator.rig import MockRig

    rig = MockRig(config.camera, config.simulator, config.imu)
    camera = imu = None
    try:
        camera, imu = rig.camera(), rig.imu()
        camera.open()
        imu.open()
    except BaseException:
        close_devices(imu, camera)
        rig.close()
        raise
    return camera, imu


def close_devices(*devices) -> None:
    """Stop and close each device; one failing (a lost device) never keeps another open."""
    for device in devices:
        if device is None:
            continue
        for step in ("stop", "close"):
            try:
                getattr(device, step)()
            except Exception as e:
                log.warning("%s %s: %s", step, type(device).__name__, e)


def devices_metadata(config: config_mod.Config, camera, imu) -> dict:
    """The "devices" metadata record: what was configured, and what the devices say."""
    cam = camera.status() if camera else None
    imu_status = imu.status() if imu else None
    return devices_record(
        config,
        camera_details=cam.details if cam else {},
        imu_info=getattr(imu, "info", {}) or {},
        imu_details=imu_status.details if imu_status else {},
    ).to_dict()
