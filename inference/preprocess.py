"""From a depth frame and the IMU orientation to the classifier's 100 x 100 binary image.

The authors' pipeline (Zhang et al., IEEE TNSRE 2019):
1. level the cloud with the IMU: camera -> IMU (mounting) -> world, then drop the heading
   so that x is the horizontal direction the camera looks at (x forward, y left, z up,
   origin at the camera);
2. keep a narrow corridor straight ahead (|y| <= corridor_width / 2);
3. remove isolated points (flying pixels, speckle);
4. project onto the sagittal plane (x forward, z up) and rasterise into 1 cm cells in the
   authors' order (their setOccupancyMap): x is shifted so that its minimum lands at one
   cell (0.01 m) and points 0.99 m or more beyond it are dropped; then z is shifted so that
   the minimum of the points left lands at 0.01 m, and points 0.99 m or more above it are
   dropped. Terrain beyond the image (a descent 1.5 m ahead) so never lifts the visible
   terrain off the image's bottom.

Image orientation: `image[row, col]`, col = forward distance (col 0 nearest), row 0 =
highest, the last row lowest; as one looks at the terrain from the walker's left side.
Column 0 and the last row are always empty (the one-cell margin of the authors' shift).

Degenerate input never raises: the result has an empty image and `flag` says why.

The parameters are `inference.config.PreprocessConfig` (the [preprocess] section) and the
camera's mounting on the IMU, `devices.config.MountingConfig` ([mounting]).
Two implementations of steps 1-3, chosen by `PreprocessConfig.backend`: "numpy" (the
default: per-pixel dot products, isolated-cell removal on the sagittal grid) and "open3d"
(tensor point cloud transform, crop and radius outlier removal). `bench_preprocess()`
measures both; numpy wins by a wide margin on a frame of 224 x 171 points.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from dataclasses import dataclass, field

import numpy as np

from devices.config import MountingConfig
from devices.rotations import matrix_to_quat, mounting_matrix, quat_normalize
from inference.config import PreprocessConfig

log = logging.getLogger(__name__)

# Flags: why an image is empty.
NO_VALID_POINTS = "no_valid_points"
EMPTY_CORRIDOR = "empty_corridor"
LOOKING_UP = "looking_up"
BAD_ORIENTATION = "bad_orientation"
# The IMU orientation at the frame's time is older than max_orientation_age_ms (the IMU is
# silent or unplugged): a held orientation would level the cloud wrongly, so no image.
STALE_ORIENTATION = "stale_orientation"
# Frames no orientation can level (stale, or not a rotation at all): no image, no CNN, the
# fusion not fed, so nothing is decided on a cloud that cannot be trusted.
UNDECIDED = (STALE_ORIENTATION, BAD_ORIENTATION)
NAN_INPUT = "nan_input"
BAD_INPUT = "bad_input"

BACKENDS = ("numpy", "open3d")  # PreprocessConfig.backend
NOMINAL_MOUNTING = MountingConfig()


def metadata(params: PreprocessConfig, mounting: MountingConfig) -> dict:
    """The preprocessing as recordings and models keep it: every parameter, and the
    mounting's angles as mounting_roll_deg, mounting_pitch_deg, mounting_yaw_deg."""
    out: dict = {}
    for name, value in dataclasses.asdict(params).items():
        if name == "outlier_min_points":
            out |= {f"mounting_{k}": float(v) for k, v in dataclasses.asdict(mounting).items()}
        out[name] = value
    return out


@dataclass
class Preprocessed:
    """One frame, preprocessed. See the module docstring for the image orientation."""

    image: np.ndarray  # (grid, grid) uint8 0/1; row 0 highest, col 0 nearest
    cloud: np.ndarray  # (N, 3) float32 leveled corridor points: x fwd, y left, z up (m)
    profile: np.ndarray  # (M, 2) float32 sagittal points (forward x, height z), metres
    flag: str = ""  # "" when fine, else why the image is empty
    elevation_deg: float = float("nan")  # optical axis above the horizon (negative: down)
    # (x, z) in metres of the image's lower-left corner: column c spans
    # x0 + c * cell .. x0 + (c + 1) * cell, row r spans z0 + (grid - 1 - r) * cell ..
    origin_m: tuple[float, float] = (float("nan"), float("nan"))
    details: dict = field(default_factory=dict)  # counts for diagnostics

    @property
    def ok(self) -> bool:
        return not self.flag


def empty(
    params: PreprocessConfig, flag: str, elevation_deg: float = float("nan"), **details
) -> Preprocessed:
    return Preprocessed(
        image=np.zeros((params.grid_size, params.grid_size), np.uint8),
        cloud=np.zeros((0, 3), np.float32),
        profile=np.zeros((0, 2), np.float32),
        flag=flag,
        elevation_deg=elevation_deg,
        details=details,
    )


@functools.lru_cache(maxsize=16)
def _mounting(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    return mounting_matrix(roll_deg, pitch_deg, yaw_deg)


def _rotation(q: np.ndarray) -> np.ndarray:
    """devices.rotations.quat_to_matrix of one quaternion, bit for bit (its normalisation,
    then the same float operations on Python floats instead of numpy's 0-d arrays)."""
    w, x, y, z = quat_normalize(q).tolist()
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def leveling_matrix(
    quaternion: np.ndarray, mounting: MountingConfig = NOMINAL_MOUNTING
) -> np.ndarray | None:
    """Camera -> leveled frame (x forward along the camera's heading, y left, z up).

    None when the quaternion is not a rotation (NaN, zero, far from unit length).
    """
    q = np.asarray(quaternion, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        return None
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 2.0:  # a real orientation filter never drifts this far
        return None
    cam_to_world = _rotation(q / norm) @ _mounting(
        float(mounting.roll_deg), float(mounting.pitch_deg), float(mounting.yaw_deg)
    )
    axis = cam_to_world[:, 2]  # the optical axis in the world
    if np.hypot(axis[0], axis[1]) < 0.2:
        # Looking almost straight down: the top of the image points forward.
        axis = -cam_to_world[:, 1]
    heading = np.arctan2(axis[1], axis[0])
    c, s = np.cos(heading), np.sin(heading)
    unyaw = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return unyaw @ cam_to_world


def camera_orientation(
    quaternion: np.ndarray, mounting: MountingConfig = NOMINAL_MOUNTING
) -> np.ndarray | None:
    """The camera's orientation in the leveled frame the clouds are in, [w, x, y, z]
    (camera -> leveled world: leveling_matrix as a quaternion); None where the IMU's
    quaternion is not a rotation. Its optical axis rises elevation_deg above the horizon."""
    level = None if quaternion is None else leveling_matrix(quaternion, mounting)
    return None if level is None else matrix_to_quat(level)


def preprocess(
    xyz: np.ndarray,
    confidence: np.ndarray,
    quaternion: np.ndarray,
    params: PreprocessConfig,
    orientation_age_ns: int = 0,
    mounting: MountingConfig = NOMINAL_MOUNTING,
    *,
    compiled: bool = True,
) -> Preprocessed:
    """Level, crop, clean and rasterise one depth frame (see the module docstring).

    xyz: (H, W, 3) metres, camera frame; confidence: (H, W), 0 = invalid;
    quaternion: [w, x, y, z] IMU -> world at the frame's time; orientation_age_ns: how far
    the quaternion is from the IMU sample it comes from (capture.live.pipeline.OrientationTrack);
    mounting: the camera's orientation on the IMU. compiled False: the numpy backend's
    straightforward functions (the reference inference.corridor is tested against) instead
    of their compiled steps; the same result, bit for bit.
    """
    xyz = np.asarray(xyz)
    confidence = np.asarray(confidence)
    if xyz.ndim != 3 or xyz.shape[-1] != 3 or confidence.shape != xyz.shape[:2]:
        return empty(params, BAD_INPUT, shape=list(xyz.shape))
    return _preprocess(
        lambda: xyz.reshape(-1, 3),
        xyz,
        confidence,
        quaternion,
        params,
        orientation_age_ns,
        mounting,
        compiled,
    )


def preprocess_ranges(
    range_mm: np.ndarray,
    rays: np.ndarray,
    confidence: np.ndarray,
    quaternion: np.ndarray,
    params: PreprocessConfig,
    orientation_age_ns: int = 0,
    mounting: MountingConfig = NOMINAL_MOUNTING,
) -> Preprocessed:
    """preprocess() of the points that ranges in mm ((H, W) uint16) along the camera's unit
    rays ((H, W, 3) float32) make (capture.recording.topics.xyz_from_range): a recording's
    frame, without building its points first where they are not needed."""
    range_mm, confidence = np.asarray(range_mm), np.asarray(confidence)
    if (
        range_mm.ndim != 2
        or rays.shape != (*range_mm.shape, 3)
        or confidence.shape != range_mm.shape
        or params.backend != "numpy"
    ):
        xyz = (range_mm.astype(np.float32)[..., None] * np.float32(0.001)) * rays
        return preprocess(xyz, confidence, quaternion, params, orientation_age_ns, mounting)
    from inference.corridor import points_from_ranges

    def points() -> np.ndarray:
        return points_from_ranges(range_mm, rays.astype(np.float32, copy=False))

    return _preprocess(
        points, None, confidence, quaternion, params, orientation_age_ns, mounting, True
    )


def _preprocess(
    points, xyz, confidence, quaternion, params, orientation_age_ns, mounting, compiled
) -> Preprocessed:
    """preprocess() once its input is checked: `points()` makes the (N, 3) points (xyz
    flattened; xyz None: the open3d backend is not asked for)."""
    if orientation_age_ns > params.max_orientation_age_ms * 1e6:
        return empty(params, STALE_ORIENTATION, age_ms=orientation_age_ns * 1e-6)
    level = leveling_matrix(quaternion, mounting)
    if level is None:
        return empty(params, BAD_ORIENTATION)
    elevation = float(np.degrees(np.arcsin(np.clip(level[2, 2], -1.0, 1.0))))
    if elevation > params.max_elevation_deg:
        return empty(params, LOOKING_UP, elevation)

    flat = None
    if params.backend == "open3d":
        cloud = _corridor_open3d(xyz, confidence, level, params)
    elif compiled:
        flat = points()
        cloud = _corridor_compiled(flat, confidence, level, params)
    else:
        flat = points()
        cloud = _corridor_numpy(flat, confidence, level, params)

    if len(cloud) < params.min_points:
        flat = points() if flat is None else flat
        valid = confidence.reshape(-1) >= params.min_confidence
        n_valid = int(np.count_nonzero(valid))
        if n_valid == 0:
            return empty(params, NO_VALID_POINTS, elevation)
        n_finite = int(np.count_nonzero(np.isfinite(flat[valid]).all(axis=1)))
        if n_finite == 0:
            return empty(params, NAN_INPUT, elevation, valid=n_valid)
        return empty(params, EMPTY_CORRIDOR, elevation, valid=n_valid, corridor=len(cloud))

    profile = np.ascontiguousarray(cloud[:, [0, 2]])
    if compiled:
        from inference import corridor

        grid, cell = params.grid_size, params.cell_m
        image, x_min, z_min = corridor.rasterise(profile, grid, np.float32(1.0 / cell))
        origin = (float(x_min) - cell, float(z_min) - cell)
    else:
        image, origin = rasterise(profile, params.grid_size, params.cell_m)
    return Preprocessed(
        image=image,
        cloud=cloud,
        profile=profile,
        elevation_deg=elevation,
        origin_m=origin,
        details={"corridor": len(cloud)},
    )


def preprocess_frame(
    frame,
    quaternion: np.ndarray,
    params: PreprocessConfig,
    orientation_age_ns: int = 0,
    mounting: MountingConfig = NOMINAL_MOUNTING,
) -> Preprocessed:
    """preprocess() on a devices.frames.DepthFrame."""
    return preprocess(frame.xyz, frame.confidence, quaternion, params, orientation_age_ns, mounting)


def rasterise(
    profile: np.ndarray, grid: int = 100, cell_m: float = 0.01
) -> tuple[np.ndarray, tuple[float, float]]:
    """The authors' binary image of sagittal points (x forward, z up); and its origin.

    Their order: the x shift and crop first, then the z shift by the minimum height of the
    points the x crop kept, then the z crop.
    """
    image = np.zeros((grid, grid), np.uint8)
    x, z = profile[:, 0], profile[:, 1]
    x_min = float(x.min())
    # The minimum lands in cell 1 (at 0.01 m), as the authors shift it.
    col = ((x - x_min) * (1.0 / cell_m)).astype(np.int32) + 1
    in_x = col < grid
    col, z = col[in_x], z[in_x]
    z_min = float(z.min())
    up = ((z - z_min) * (1.0 / cell_m)).astype(np.int32) + 1
    keep = up < grid
    image[grid - 1 - up[keep], col[keep]] = 1
    return image, (x_min - cell_m, z_min - cell_m)


def _corridor_compiled(
    flat: np.ndarray, confidence: np.ndarray, level: np.ndarray, params: PreprocessConfig
) -> np.ndarray:
    """_corridor_numpy by inference.corridor's steps, the dot products by numpy's."""
    from inference import corridor

    rows = level.astype(np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        y = flat @ rows[1]
    keep = corridor.corridor_indices(
        y,
        confidence.reshape(-1),
        np.float32(params.corridor_width_m / 2),
        params.min_confidence,
    )
    near = corridor.gather(flat, keep)
    with np.errstate(invalid="ignore", over="ignore"):
        x = near @ rows[0]
        z = near @ rows[2]
    f32 = np.float32
    return corridor.corridor_cloud(
        x,
        y,
        z,
        keep,
        f32(params.min_forward_m),
        f32(params.max_forward_m),
        f32(params.min_height_m),
        f32(params.max_height_m),
        f32(1.0 / params.outlier_cell_m),
        params.outlier_min_points,
    )


def _corridor_numpy(
    flat: np.ndarray, confidence: np.ndarray, level: np.ndarray, params: PreprocessConfig
) -> np.ndarray:
    rows = level.astype(np.float32)
    # Crop on y (and confidence) before computing x and z: nine pixels in ten leave here.
    # NaNs fail every test.
    with np.errstate(invalid="ignore", over="ignore"):
        y = flat @ rows[1]
    half = params.corridor_width_m / 2
    keep = np.flatnonzero((np.abs(y) <= half) & (confidence.reshape(-1) >= params.min_confidence))
    near = flat[keep]
    with np.errstate(invalid="ignore", over="ignore"):
        x = near @ rows[0]
        z = near @ rows[2]
    inside = (
        (x >= params.min_forward_m)
        & (x <= params.max_forward_m)
        & (z >= params.min_height_m)
        & (z <= params.max_height_m)
    )
    cloud = np.stack([x[inside], y[keep[inside]], z[inside]], axis=1)
    if params.outlier_min_points > 1 and len(cloud):
        cloud = cloud[
            _dense_cells(cloud[:, 0], cloud[:, 2], params.outlier_cell_m, params.outlier_min_points)
        ]
    return cloud


def _dense_cells(x: np.ndarray, z: np.ndarray, cell_m: float, min_points: int) -> np.ndarray:
    """Mask of the points whose 3 x 3 sagittal cells hold at least min_points points."""
    ix = ((x - x.min()) * (1.0 / cell_m)).astype(np.int32) + 1  # one empty cell around
    iz = ((z - z.min()) * (1.0 / cell_m)).astype(np.int32) + 1
    width, height = int(ix.max()) + 2, int(iz.max()) + 2
    counts = np.bincount(iz * width + ix, minlength=width * height).reshape(height, width)
    # 3 x 3 box sums from an integral image.
    integral = np.zeros((height + 1, width + 1), np.int32)
    np.cumsum(np.cumsum(counts, axis=0), axis=1, out=integral[1:, 1:])
    box = integral[3:, 3:] - integral[:-3, 3:] - integral[3:, :-3] + integral[:-3, :-3]
    return box[iz - 1, ix - 1] >= min_points


def _corridor_open3d(
    xyz: np.ndarray, confidence: np.ndarray, level: np.ndarray, params: PreprocessConfig
) -> np.ndarray:
    import open3d as o3d

    o3c = o3d.core
    points = xyz[confidence >= params.min_confidence].astype(np.float32, copy=False)
    if len(points) == 0:
        return np.zeros((0, 3), np.float32)
    cloud = o3d.t.geometry.PointCloud(o3c.Tensor(points))
    transform = np.eye(4)
    transform[:3, :3] = level
    cloud = cloud.transform(o3c.Tensor(transform, dtype=o3c.float32))
    half = params.corridor_width_m / 2
    box = o3d.t.geometry.AxisAlignedBoundingBox(
        o3c.Tensor([params.min_forward_m, -half, params.min_height_m], dtype=o3c.float32),
        o3c.Tensor([params.max_forward_m, half, params.max_height_m], dtype=o3c.float32),
    )
    cloud = cloud.crop(box)
    if params.outlier_min_points > 1 and not cloud.is_empty():
        cloud, _ = cloud.remove_radius_outliers(
            params.outlier_min_points, 1.5 * params.outlier_cell_m
        )
    if cloud.is_empty():
        return np.zeros((0, 3), np.float32)
    return cloud.point.positions.numpy().astype(np.float32, copy=False)
