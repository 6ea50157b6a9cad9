"""Test fixture: ray-cast a known sagittal terrain through a pinhole camera.

The terrain is a polyline in the vertical plane along the camera's heading (forward s,
height z, ground under the camera at z = 0), extruded sideways. The camera sits `height_m`
above the origin; its orientation is the IMU quaternion (IMU -> world) times the mounting
(camera -> IMU). Independent of the simulator other code uses: pure numpy, exact geometry.
"""

from __future__ import annotations

import numpy as np

from devices.frames import CameraGeometry
from devices.rotations import mounting_matrix, quat_from_euler, quat_to_matrix

GEOMETRY = CameraGeometry()


def level() -> list[tuple[float, float]]:
    return [(-5.0, 0.0), (10.0, 0.0)]


def ramp(angle_deg: float, start_m: float | None = None) -> list[tuple[float, float]]:
    """A plane rising (positive angle) or falling: through the ground under the camera,
    or level ground up to `start_m` ahead and the ramp from there."""
    k = np.tan(np.radians(angle_deg))
    if start_m is None:
        return [(-5.0, -5.0 * k), (10.0, 10.0 * k)]
    return [(-5.0, 0.0), (start_m, 0.0), (10.0, (10.0 - start_m) * k)]


def stairs(
    riser_m: float, tread_m: float, first_m: float = 0.2, steps: int = 4, up: bool = True
) -> list[tuple[float, float]]:
    """Level ground, then `steps` steps up (or down) starting `first_m` ahead, then a landing."""
    sign = 1.0 if up else -1.0
    pts = [(-5.0, 0.0)]
    s, z = first_m, 0.0
    for _ in range(steps):
        pts.append((s, z))
        z += sign * riser_m
        pts.append((s, z))
        s += tread_m
    pts.append((10.0, z))
    return pts


def thigh_quaternion(
    pitch_deg: float = 0.0, roll_deg: float = 0.0, yaw_deg: float = 0.0
) -> np.ndarray:
    return quat_from_euler(np.radians(roll_deg), np.radians(pitch_deg), np.radians(yaw_deg))


def render(
    terrain: list[tuple[float, float]],
    quaternion: np.ndarray,
    mounting: tuple[float, float, float] = (0.0, 35.0, 0.0),
    height_m: float = 0.55,
    noise_m: float = 0.0,
    seed: int = 0,
    geometry: CameraGeometry = GEOMETRY,
) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (H, W, 3) float32 camera frame, confidence (H, W) uint8) as a ToF camera gives.

    noise_m: uniform range noise in [-noise_m, +noise_m] along each ray.
    """
    rays = geometry.rays().reshape(-1, 3).astype(np.float64)
    cam_to_world = quat_to_matrix(quaternion) @ mounting_matrix(*mounting)
    d = rays @ cam_to_world.T
    axis = cam_to_world[:, 2]
    heading = np.arctan2(axis[1], axis[0])
    ds = d[:, 0] * np.cos(heading) + d[:, 1] * np.sin(heading)
    dz = d[:, 2]
    t_best = np.full(len(rays), np.inf)
    for (s0, z0), (s1, z1) in zip(terrain[:-1], terrain[1:]):
        es, ez = s1 - s0, z1 - z0
        denom = ds * ez - dz * es
        with np.errstate(divide="ignore", invalid="ignore"):
            # origin (0, height): solve origin + t d = a + u e
            ws, wz = s0 - 0.0, z0 - height_m
            t = (ws * ez - wz * es) / denom
            u = (ws * dz - wz * ds) / denom
        hit = (np.abs(denom) > 1e-12) & (t > 1e-6) & (u >= 0) & (u <= 1)
        t_best = np.where(hit & (t < t_best), t, t_best)
    if noise_m:
        t_best = t_best + np.random.default_rng(seed).uniform(-noise_m, noise_m, len(rays))
    # A ToF camera reports range along the ray; xyz = t * ray.
    valid = (
        np.isfinite(t_best)
        & (t_best * rays[:, 2] >= geometry.min_range_m)
        & (t_best <= geometry.max_range_m)
    )
    xyz = np.where(valid[:, None], rays * np.where(valid, t_best, 0.0)[:, None], 0.0)
    shape = (geometry.height, geometry.width)
    return (
        xyz.reshape(*shape, 3).astype(np.float32),
        np.where(valid, 200, 0).astype(np.uint8).reshape(shape),
    )
