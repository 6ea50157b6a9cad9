"""The ToF model measured the way its figures are stated.

    python -m devices.simulator.sensor_check


- `facing_noise`: depth noise sigma / distance on a mid-grey surface facing the camera, the
  datasheet's setting (<= 1 % at 5 fps over 0.5-4 m, <= 2 % at 45 fps over 0.1-1 m);
- `level_band`: the band level ground makes in the classifier's image at a forward
  distance: depth noise along the rays, its height spread, and the rows it covers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from devices.frames import CameraGeometry
from devices.rotations import mounting_matrix
from devices.simulator.course import make_course
from devices.simulator.render import Hits, TerrainScene, ToFParams, ToFSensor, use_case

CAMERA_HEIGHT_M = 0.55
CAMERA_TILT_DEG = 35.0
CORRIDOR_M = 0.1


def facing_noise(fps: float, distance_m: float, frames: int = 10, seed: int = 0) -> float:
    """Measured depth sigma / distance of the central pixels on a surface at `distance_m`
    facing the camera (albedo 0.45)."""
    g = CameraGeometry()
    sensor = ToFSensor(g, ToFParams.for_scene(False, fps), seed)
    rays = sensor.rays_cam
    rows, cols = np.divmod(np.arange(len(rays)), g.width)
    centre = (np.abs(rows - g.cy) < 15) & (np.abs(cols - g.cx) < 15)
    t = (distance_m / rays[:, 2]).astype(np.float32)
    errors = []
    rng = np.random.default_rng(seed)
    for _ in range(frames):
        hits = Hits(t.copy(), np.zeros(len(t), np.int32), rays[:, 2].copy(), np.full_like(t, 0.45))
        xyz, confidence, _ = sensor.apply(hits, rng)
        keep = centre & (confidence.ravel() > 0)
        errors.append(np.linalg.norm(xyz.reshape(-1, 3)[keep], axis=1) - t[keep])
    return float(np.std(np.concatenate(errors)) / distance_m)


@dataclass(frozen=True)
class Band:
    forward_m: float
    range_m: float  # camera to the ground there
    depression_deg: float  # the ray below the horizon
    sigma_depth_m: float  # measured depth noise along the rays
    expected_sigma_depth_m: float  # the model's: datasheet figure x weak-return factor
    sigma_height_m: float  # measured height spread of the leveled points
    rows: int  # 1 cm rows holding 90 % of the points (5th to 95th percentile)
    valid_share: float  # of the corridor pixels there


def level_band(
    forward_m: float, fps: float = 15.0, outdoor: bool = False, frames: int = 10, seed: int = 0
) -> Band:
    """Level ground `forward_m` ahead (+- 5 cm) of a standing walker's thigh camera."""
    g = CameraGeometry()
    course = make_course("outdoor" if outdoor else "indoor", seed, modes=("LG",))
    course = type(course)(course.segments, course.preset, seed)  # no walls, no clutter, flat
    params = ToFParams.for_course(course, fps)
    sensor = ToFSensor(g, params, seed)
    scene = TerrainScene(course, sensor.rays_cam)
    pose = np.eye(4)
    pose[:3, :3] = mounting_matrix(0.0, CAMERA_TILT_DEG, 0.0)
    pose[:3, 3] = (1.0, 0.0, CAMERA_HEIGHT_M)
    rng = np.random.default_rng(seed)
    depth_errors, heights, expected, valid, total = [], [], [], 0, 0
    for _ in range(frames):
        hits = scene.cast(pose)
        true_world = pose[:3, 3] + hits.t[:, None] * (sensor.rays_cam @ pose[:3, :3].T)
        with np.errstate(invalid="ignore"):
            here = (np.abs(true_world[:, 1]) <= CORRIDOR_M / 2) & (
                np.abs(true_world[:, 0] - 1.0 - forward_m) <= 0.05
            )
        amplitude = hits.albedo * hits.cos_inc * sensor.vignetting / np.square(hits.t)
        expected.append(params.noise_sigma(hits.t[here], amplitude[here]))
        t_true = hits.t[here]
        xyz, confidence, _ = sensor.apply(hits, rng)
        ok = confidence.ravel()[here] > 0
        total += int(here.sum())
        valid += int(ok.sum())
        points = xyz.reshape(-1, 3)[here][ok].astype(np.float64)
        depth_errors.append(np.linalg.norm(points, axis=1) - t_true[ok])
        heights.append((points @ pose[:3, :3].T)[:, 2] + CAMERA_HEIGHT_M)
    z = np.concatenate(heights)
    lo, hi = np.percentile(z, [5, 95])
    range_m = float(np.hypot(forward_m, CAMERA_HEIGHT_M))
    return Band(
        forward_m=forward_m,
        range_m=range_m,
        depression_deg=float(np.degrees(np.arctan2(CAMERA_HEIGHT_M, forward_m))),
        sigma_depth_m=float(np.std(np.concatenate(depth_errors))),
        expected_sigma_depth_m=float(np.sqrt(np.mean(np.concatenate(expected) ** 2))),
        sigma_height_m=float(np.std(z)),
        rows=int(np.floor(hi / 0.01) - np.floor(lo / 0.01)) + 1,
        valid_share=valid / max(total, 1),
    )


def main() -> None:
    for fps, distances in (
        (5.0, (0.5, 1.0, 2.0, 3.5)),
        (15.0, (0.5, 1.0, 2.0)),
        (45.0, (0.5, 1.0)),
    ):
        name = use_case(fps)[0]
        figures = "  ".join(f"{d:g} m {facing_noise(fps, d) * 100:.2f} %" for d in distances)
        print(f"{name}: facing surface, sigma / distance: {figures}")
    for outdoor in (False, True):
        print(f"level ground, {'outdoor' if outdoor else 'indoor'}, MODE_9_15FPS_700:")
        for d in (0.5, 1.0, 2.0):
            b = level_band(d, outdoor=outdoor)
            print(
                f"  {d:g} m ahead (range {b.range_m:.2f} m, {b.depression_deg:.0f} deg down): "
                f"depth sigma {b.sigma_depth_m * 100:.2f} cm "
                f"(model {b.expected_sigma_depth_m * 100:.2f}, "
                f"{b.sigma_depth_m / b.range_m * 100:.2f} % of range), height sigma "
                f"{b.sigma_height_m * 100:.2f} cm, {b.rows} rows, {b.valid_share:.0%} valid"
            )


if __name__ == "__main__":
    main()
