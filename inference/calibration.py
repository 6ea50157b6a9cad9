"""Camera mounting (camera -> IMU roll and pitch) from frames of level ground.

The subject stands still on level floor. In every frame the floor is the dominant plane
(Open3D RANSAC plane segmentation, refined by a least-squares fit on its inliers); its
upward normal in the camera frame must map, through the mounting and the IMU orientation,
onto the world's up. The roll and pitch that do this best over all frames are the new
mounting; yaw (about gravity when standing) is not observable from a floor and is kept.

Pure: frames and orientations in, a CalibrationResult out. `walkcap calibrate` collects
the frames and writes the result to the configuration.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from devices.rotations import mounting_matrix, quat_normalize, quat_to_matrix
from inference.errors import InferenceError

log = logging.getLogger(__name__)

PLANE_DISTANCE_M = 0.015  # RANSAC inlier distance (ToF noise on a floor: a few mm)
MIN_INLIER_FRACTION = 0.5  # the floor must be most of what the camera sees
MAX_OFFSET_DEG = 25.0  # floor normal vs. up predicted by the current mounting
MAX_MOTION_DEG = 2.0  # spread of gravity in the IMU frame across frames: subject moved
MAX_HEIGHT_SPREAD_M = 0.03
MIN_FRAMES = 3
REFIT_ROUNDS = 5  # least-squares refits of RANSAC's plane on its own inliers
MAX_POINTS = 10000  # per frame, subsampled evenly: plenty for a plane


class CalibrationError(InferenceError):
    """Calibration refused: the floor was not found or the subject moved."""


@dataclass
class CalibrationResult:
    roll_deg: float
    pitch_deg: float
    yaw_deg: float  # kept from the current mounting (not observable from a floor)
    previous: tuple[float, float, float]
    inlier_fraction: float = 0.0  # median share of points on the floor plane
    plane_rms_m: float = float("nan")  # median RMS distance of the floor inliers
    residual_deg: float = float("nan")  # RMS angle between mapped floor normals and up
    camera_height_m: float = float("nan")  # median camera height above the floor
    motion_deg: float = float("nan")  # largest deviation of gravity (IMU frame) from mean
    frames_used: int = 0
    frames_total: int = 0
    problem: str = ""  # "" when the result can be used, else why not
    per_frame: list[dict] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problem

    @property
    def change_deg(self) -> tuple[float, float]:
        return self.roll_deg - self.previous[0], self.pitch_deg - self.previous[1]


def floor_plane(
    xyz: np.ndarray, confidence: np.ndarray, min_confidence: int = 1, seed: int = 0
) -> tuple[np.ndarray, float, float, float] | None:
    """The dominant plane of one frame: (upward unit normal in the camera frame, camera
    height above it, inlier fraction, RMS distance of the inliers); None without points."""
    import open3d as o3d

    pts = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    valid = (np.asarray(confidence).reshape(-1) >= min_confidence) & np.all(
        np.isfinite(pts), axis=1
    )
    pts = pts[valid]
    pts = pts[np.linalg.norm(pts, axis=1) > 0.05]  # (0, 0, 0) is "no measurement"
    if len(pts) < 100:
        return None
    pts = pts[:: max(1, len(pts) // MAX_POINTS)]
    o3d.utility.random.seed(seed)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(pts)))
    _, inliers = cloud.segment_plane(PLANE_DISTANCE_M, 3, 500)
    inliers = inliers.numpy()
    if len(inliers) < 50:
        return None
    # RANSAC's plane comes from three points: its inliers are a band tilted with it, and
    # one least-squares fit on them keeps part of that tilt. Refit on the points near the
    # refitted plane until they stay the same (a few rounds).
    every = pts.astype(np.float64)
    on_plane = every[inliers]
    for _ in range(REFIT_ROUNDS):
        centre = on_plane.mean(axis=0)
        normal = np.linalg.svd(on_plane - centre, full_matrices=False)[2][2]
        near = np.abs((every - centre) @ normal) <= PLANE_DISTANCE_M
        if near.sum() < 50 or np.array_equal(near.nonzero()[0], inliers):
            break
        inliers = near.nonzero()[0]
        on_plane = every[inliers]
    centre = on_plane.mean(axis=0)
    normal = np.linalg.svd(on_plane - centre, full_matrices=False)[2][2]
    if normal @ centre > 0:  # point from the floor towards the camera (the origin)
        normal = -normal
    height = float(-(normal @ centre))
    rms = float(np.sqrt(np.mean(((on_plane - centre) @ normal) ** 2)))
    return normal, height, len(inliers) / len(pts), rms


def estimate_mounting(
    xyz_frames: list[np.ndarray],
    confidence_frames: list[np.ndarray],
    quaternions: list[np.ndarray],
    current: tuple[float, float, float] = (0.0, 35.0, 0.0),
    min_confidence: int = 1,
) -> CalibrationResult:
    """New mounting roll/pitch from frames of level floor taken while standing still.

    quaternions: IMU -> world at each frame's time. The result's `problem` says why it
    must not be used (no floor, subject moved, too few frames); it never raises.
    """
    roll0, pitch0, yaw0 = (float(v) for v in current)
    result = CalibrationResult(
        roll0, pitch0, yaw0, (roll0, pitch0, yaw0), frames_total=len(xyz_frames)
    )
    m_current = mounting_matrix(roll0, pitch0, yaw0)
    normals, ups, heights, fractions, rmss = [], [], [], [], []
    for k, (xyz, conf, q) in enumerate(zip(xyz_frames, confidence_frames, quaternions)):
        q = np.asarray(q, dtype=np.float64)
        entry: dict = {"frame": k}
        result.per_frame.append(entry)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 0.5:
            entry["rejected"] = "no orientation"
            continue
        up_imu = quat_to_matrix(quat_normalize(q)).T @ np.array([0.0, 0.0, 1.0])
        plane = floor_plane(xyz, conf, min_confidence, seed=k)
        if plane is None:
            entry["rejected"] = "no points"
            continue
        normal, height, fraction, rms = plane
        offset = _angle_deg(m_current @ normal, up_imu)
        entry.update(inlier_fraction=fraction, height_m=height, offset_deg=offset)
        if fraction < MIN_INLIER_FRACTION or offset > MAX_OFFSET_DEG or height <= 0.05:
            entry["rejected"] = "no floor"
            continue
        normals.append(normal)
        ups.append(up_imu)
        heights.append(height)
        fractions.append(fraction)
        rmss.append(rms)

    result.frames_used = len(normals)
    if result.frames_used:
        result.inlier_fraction = float(np.median(fractions))
        result.plane_rms_m = float(np.median(rmss))
        result.camera_height_m = float(np.median(heights))
    needed = max(MIN_FRAMES, (result.frames_total + 1) // 2)
    if result.frames_used < needed:
        result.problem = (
            f"the floor was not found: {result.frames_used} of "
            f"{result.frames_total} frames show a level floor "
            f"(need {needed}); stand on open level ground, camera unobstructed"
        )
        return result
    ups_a, normals_a = np.array(ups), np.array(normals)
    mean_up = ups_a.mean(axis=0)
    mean_up /= np.linalg.norm(mean_up)
    result.motion_deg = float(max(_angle_deg(u, mean_up) for u in ups_a))
    height_spread = float(np.ptp(heights))
    mean_normal = normals_a.mean(axis=0)
    mean_normal /= np.linalg.norm(mean_normal)
    view_motion = float(max(_angle_deg(n, mean_normal) for n in normals_a))
    if (
        result.motion_deg > MAX_MOTION_DEG
        or view_motion > MAX_MOTION_DEG
        or height_spread > MAX_HEIGHT_SPREAD_M
    ):
        result.problem = (
            f"the subject moved: the thigh turned {result.motion_deg:.1f} deg, "
            f"the view {view_motion:.1f} deg, the camera height changed "
            f"{100 * height_spread:.1f} cm (limits {MAX_MOTION_DEG:.0f} deg, "
            f"{100 * MAX_HEIGHT_SPREAD_M:.0f} cm); stand still and try again"
        )
        return result

    roll, pitch = _fit_roll_pitch(normals_a, ups_a, roll0, pitch0, yaw0)
    m_new = mounting_matrix(roll, pitch, yaw0)
    errors = [_angle_deg(m_new @ n, u) for n, u in zip(normals_a, ups_a)]
    result.roll_deg, result.pitch_deg = roll, pitch
    result.residual_deg = float(np.sqrt(np.mean(np.square(errors))))
    return result


def _fit_roll_pitch(
    normals: np.ndarray, ups: np.ndarray, roll0: float, pitch0: float, yaw: float
) -> tuple[float, float]:
    from scipy.optimize import least_squares

    def residuals(angles: np.ndarray) -> np.ndarray:
        m = mounting_matrix(angles[0], angles[1], yaw)
        return (normals @ m.T - ups).ravel()

    fit = least_squares(residuals, x0=[roll0, pitch0], x_scale=10.0)
    roll, pitch = (float(v) for v in fit.x)
    return (roll + 180.0) % 360.0 - 180.0, pitch


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
