"""Synthetic depth frames: a fixed scene, cheap to make, for the recorder's benchmark and tests.

Level ground and a step ahead seen from a swinging thigh, without the walk simulator's
cost, so that a benchmark of the recorder measures the recorder.
"""

from __future__ import annotations

import numpy as np

from devices.frames import CameraGeometry, DepthFrame
from devices.rotations import mounting_matrix, quat_from_euler, quat_to_matrix


def synthetic_frame(index: int, time_ns: int, noise: float = 0.01, seed: int = 0, geometry=None):
    """A depth frame like the pico flexx gives on a thigh while walking: level ground and a
    step ahead, range noise `noise` x range (the sensor's ~1 %), confidence 0 where invalid."""
    g = geometry or CameraGeometry()
    rng = np.random.default_rng(seed * 100_003 + index)
    rays = g.rays().reshape(-1, 3).astype(np.float64)
    swing = np.radians(20.0) * np.sin(2 * np.pi * index / 45.0)  # thigh swing, ~1 Hz
    cam_to_world = quat_to_matrix(quat_from_euler(0.0, swing, 0.0)) @ mounting_matrix(0, 35, 0)
    d = rays @ cam_to_world.T
    height = 0.55
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[:, 2] < -1e-6, height / -d[:, 2], np.inf)
        step_x = 1.0 + 0.3 * np.sin(index / 90.0)
        t_step = np.where(d[:, 0] > 1e-6, step_x / d[:, 0], np.inf)
    z_step = height + t_step * d[:, 2]
    t = np.where((t_step < t) & (z_step < 0.17) & (z_step > 0), t_step, t)
    valid = np.isfinite(t) & (t >= g.min_range_m) & (t <= g.max_range_m)
    t = np.where(valid, t * (1 + noise * rng.standard_normal(len(t))), 0.0)
    xyz = (rays * t[:, None]).astype(np.float32).reshape(g.height, g.width, 3)
    confidence = np.where(valid, 255, 0).astype(np.uint8).reshape(g.height, g.width)
    gray = (np.where(valid, 4000 / np.maximum(t, 0.1) ** 2, 0)).astype(np.uint16)
    return DepthFrame(
        index=index,
        device_time_ns=time_ns,
        host_time_ns=time_ns + 2_000_000,
        xyz=xyz,
        confidence=confidence,
        gray=gray.reshape(g.height, g.width),
        geometry=g,
        truth={"mode": "LG", "pose": np.eye(4)},
    )


def corridor_cloud(frame, corridor_m: float = 0.1, forward_m: float = 1.5) -> np.ndarray:
    """The leveled points of a synthetic frame in the walking corridor, in pixel order, as
    the preprocessing passes them (about 3000 points on the synthetic scene)."""
    swing = np.radians(20.0) * np.sin(2 * np.pi * frame.index / 45.0)
    level = quat_to_matrix(quat_from_euler(0.0, swing, 0.0)) @ mounting_matrix(0, 35, 0)
    points = frame.xyz[frame.confidence > 0].astype(np.float64) @ level.T
    keep = (
        (np.abs(points[:, 1]) <= corridor_m / 2) & (points[:, 0] >= 0) & (points[:, 0] <= forward_m)
    )
    return (points[keep] - [0.0, 0.0, 0.55]).astype(np.float32)
