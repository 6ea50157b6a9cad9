"""Rendering: ray casting the course with Open3D, then what a ToF camera does to depth.

`TerrainScene` builds the course's triangle mesh and Open3D's RaycastingScene once and
casts one ray per pixel (camera rays precomputed once). The ToF model (`ToFSensor`), after
the pico flexx datasheet and the royale pipeline's defaults (sources in ToFParams):
- depth noise by use case and distance: the datasheet gives <= 1 % of the distance at
  5 fps (MODE_9_5FPS_2000, 0.5-4 m) and <= 2 % at 45 fps (MODE_5_45FPS_500, 0.1-1 m); the
  use cases between scale with their integration time (raw frames x exposure) as the two
  figures do (sigma ~ T^-1/3). That sigma holds for a return at least as strong as a
  mid-grey surface facing the camera at 4 m; weaker returns (dark, far, grazing) are
  noisier by sqrt(A_ref / A), shot noise; outdoors sunlight adds more. The noise is
  spatially correlated over about 3 x 3 pixels, as royale's adaptive noise filter leaves
  it;
- flying pixels: a pixel beside a depth edge sees both surfaces and measures a depth
  between them, weighted by their amplitudes (pmd: "in the middle between object and
  background"); royale's flying-pixel filter then invalidates a pixel whose final Z
  differs from both neighbours of a pair (left/right or above/below) by more than
  1.8 cm (Z <= 1 m) to 14 cm (Z >= 4.5 m);
- invalid pixels: beyond 0.1-4 m, at grazing incidence, too little amplitude, a noise
  sigma above royale's 7 cm threshold, the flying-pixel flag; outdoors also a speckle of
  saturated pixels. Invalid pixels have confidence 0 and xyz = 0, exactly like royale
  frames; the others a confidence from their amplitude (1-255), flying ones less.
Occluders for error images (the other foot, something in front of the lens, an object's
face ahead) are drawn analytically per ray, so the scene never changes per frame.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from devices.frames import MODES, CameraGeometry
from devices.simulator.course import Box, Course

OBSTACLE = -1  # label of wall and clutter triangles (terrain triangles: index in MODES)
NOTHING = -2  # label of a ray that hit nothing (or an occluder in front of the lens)


@dataclass
class Hits:
    """Per ray (flattened image): distance along the unit ray, label, |cos incidence|."""

    t: np.ndarray  # float32, inf where nothing was hit
    label: np.ndarray  # int32: terrain mode (index in MODES), OBSTACLE or NOTHING
    cos_inc: np.ndarray  # float32
    albedo: np.ndarray  # float32


# pico flexx use cases (royale operation modes): fps -> (name, raw frames, max exposure
# in microseconds); 8 + 1 raw frames are two modulation frequencies, 4 + 1 one.
USE_CASES = {
    5.0: ("MODE_9_5FPS_2000", 8, 2000),
    10.0: ("MODE_9_10FPS_1000", 8, 1000),
    15.0: ("MODE_9_15FPS_700", 8, 700),
    25.0: ("MODE_9_25FPS_450", 8, 450),
    35.0: ("MODE_5_35FPS_600", 4, 600),
    45.0: ("MODE_5_45FPS_500", 4, 500),
}
# The datasheet's two depth-noise figures, (integration time in us, sigma / distance).
DATASHEET_NOISE = ((8 * 2000, 0.01), (4 * 500, 0.02))


def use_case(fps: float) -> tuple[str, int, int]:
    """The use case a camera asked for `fps` runs (the nearest rate; ties: the faster)."""
    return USE_CASES[min(USE_CASES, key=lambda f: (abs(f - fps), -f))]


def datasheet_noise(fps: float) -> float:
    """Depth noise sigma / distance of the use case for `fps`: the datasheet's figure at
    5 and 45 fps, between them a power law in the integration time through both."""
    _, frames, exposure = use_case(fps)
    (t0, k0), (t1, k1) = DATASHEET_NOISE
    power = np.log(k1 / k0) / np.log(t1 / t0)
    return float(k0 * (frames * exposure / t0) ** power)


@dataclass(frozen=True)
class ToFParams:
    noise_rel: float = 0.0142  # sigma / distance (datasheet_noise(15): MODE_9_15FPS_700)
    # The return the datasheet's figure holds down to: a mid-grey surface (albedo 0.45, the
    # indoor floor) facing the camera at 4 m, the end of the 5 fps figure's range.
    reference_amplitude: float = 0.45 / 4.0**2
    max_noise_m: float = 0.07  # royale's noise threshold: a noisier pixel is invalid
    min_amplitude: float = 0.006  # below: invalid (too dark, too far, too grazing)
    full_amplitude: float = 0.25  # amplitude of full confidence (albedo 0.5 at 1.4 m)
    grazing_cos: float = 0.10  # incidence beyond ~84 degrees: invalid
    edge_jump_m: float = 0.04  # a depth edge: neighbours differ by this + 3 % of range
    # royale's flying-pixel filter: the threshold on Z rises linearly from near to far.
    flying_near: tuple[float, float] = (1.0, 0.018)  # (Z m, threshold m)
    flying_far: tuple[float, float] = (4.5, 0.14)
    speckle: float = 0.0  # share of random invalid pixels (sunlight)
    ambient_gray: float = 30.0

    @classmethod
    def for_course(cls, course: Course, fps: float = 15.0) -> ToFParams:
        return cls.for_scene(course.outdoor, fps)

    @classmethod
    def for_scene(cls, outdoor: bool, fps: float = 15.0) -> ToFParams:
        noise = datasheet_noise(fps)
        if outdoor:
            # Sunlight's shot noise (no datasheet figure): 1.6 times the indoor sigma.
            return cls(noise_rel=1.6 * noise, min_amplitude=0.009, speckle=0.01, ambient_gray=250.0)
        return cls(noise_rel=noise)

    def noise_sigma(self, distance: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
        """Depth noise sigma (m) of a return at `distance` (m) with `amplitude`."""
        weak = self.reference_amplitude / np.maximum(amplitude, 1e-9)
        return self.noise_rel * distance * np.sqrt(np.maximum(weak, 1.0))

    def flying_threshold(self, z: np.ndarray) -> np.ndarray:
        """royale's flying-pixel threshold at the final Z (m)."""
        (z0, f0), (z1, f1) = self.flying_near, self.flying_far
        return f0 + (f1 - f0) * np.clip((z - z0) / (z1 - z0), 0.0, 1.0)


def _box_triangles(box: Box) -> tuple[np.ndarray, np.ndarray]:
    c = np.array(box.center)
    h = np.array(box.size) / 2
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    v = c + corners * h
    # corner index = 4*ix + 2*iy + iz; two triangles per face
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tri = [[a, b, c_] for a, b, c_, d in faces] + [[a, c_, d] for a, b, c_, d in faces]
    return v, np.array(tri)


def course_mesh(course: Course) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (n, 3), triangles (m, 3) and per-triangle labels of the whole course.

    A terrain triangle's label is the index in MODES of its segment's mode, walls and
    clutter are OBSTACLE. The profile is extruded
    across the walkway; it starts 3 m before the course and runs 6 m past its end so that
    the camera never looks over an edge of the world.
    """
    corners = [np.array([[-3.0, 0.0]])] + [s.profile() for s in course.segments]
    corners.append(np.array([[course.segments[-1].x1 + 6.0, course.segments[-1].z1]]))
    p = np.concatenate(corners)
    keep = np.concatenate([[True], np.any(np.abs(np.diff(p, axis=0)) > 1e-9, axis=1)])
    x, z = p[keep, 0], p[keep, 1]
    # label of corner k: the terrain of the interval from corner k-1 to k
    modes = np.array([MODES.index(m) for m in course.modes])
    labels = np.concatenate([[0], modes[course.segment_index((x[:-1] + x[1:]) / 2)]])
    if course.bump_m > 0:  # uneven ground needs vertices to bend at
        x, z, labels = _subdivide(x, z, labels, 0.1)
        y = np.linspace(-course.half_width_m, course.half_width_m, 61)
    else:
        y = np.array([-course.half_width_m, course.half_width_m])
    n, m = len(x), len(y)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    zz = z[:, None] + course.bumps(xx, yy)
    vertices = np.stack([xx, yy, zz], axis=-1).reshape(-1, 3)
    i = (np.arange(n - 1)[:, None] * m + np.arange(m - 1)[None, :]).ravel()
    triangles = np.concatenate(
        [np.stack([i, i + m, i + 1], 1), np.stack([i + 1, i + m, i + m + 1], 1)]
    )
    tri_labels = np.tile(np.repeat(labels[1:], m - 1), 2)
    for box in course.boxes:
        v, t = _box_triangles(box)
        triangles = np.concatenate([triangles, t + len(vertices)])
        vertices = np.concatenate([vertices, v])
        tri_labels = np.concatenate([tri_labels, np.full(len(t), OBSTACLE, np.int32)])
    return vertices, triangles, tri_labels


def _subdivide(x, z, labels, step):
    out_x, out_z, out_l = [x[0]], [z[0]], [labels[0]]
    for k in range(1, len(x)):
        n = max(1, int(np.ceil((x[k] - x[k - 1]) / step)))
        f = np.arange(1, n + 1) / n
        out_x += list(x[k - 1] + f * (x[k] - x[k - 1]))
        out_z += list(z[k - 1] + f * (z[k] - z[k - 1]))
        out_l += [labels[k]] * n
    return np.array(out_x), np.array(out_z), np.array(out_l, dtype=np.int32)


def _threads_allowed() -> int:
    """OMP_NUM_THREADS when it is a positive integer, else the cores this process may run
    on (a CPU set or `taskset` may give it fewer than the machine has)."""
    text = os.environ.get("OMP_NUM_THREADS", "")
    if text.isdigit() and int(text) > 0:
        return int(text)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0


class TerrainScene:
    """The course as an Open3D RaycastingScene, cast from a camera pose, one ray per pixel."""

    def __init__(self, course: Course, rays_cam: np.ndarray, threads: int = 0) -> None:
        """`rays_cam`: unit ray per pixel in the camera frame, (n, 3) float32; `threads`:
        Open3D's threads per cast, 0 for all cores, or for OMP_NUM_THREADS where it is set
        (a cluster task's share of a node: Ray sets it to the task's CPUs)."""
        import open3d as o3d

        self._o3d = o3d
        vertices, triangles, labels = course_mesh(course)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(vertices.astype(np.float32)),
            o3d.core.Tensor(triangles.astype(np.uint32)),
        )
        self.triangle_count = n = len(triangles)
        # per-triangle tables with one more entry for "no hit" (primitive ids are clamped)
        self._labels = np.append(labels, NOTHING).astype(np.int32)
        self._albedo = np.where(labels >= 0, 0.3 if course.outdoor else 0.45, 0.6)
        self._albedo = np.append(self._albedo, 0.0).astype(np.float32)
        self._no_hit = np.uint32(n)
        # rays = [1, direction] @ [[origin, 0], [0, R^T]]: origin and direction in one product
        self._homogeneous = np.hstack([np.ones((len(rays_cam), 1), np.float32), rays_cam])
        self._transform = np.zeros((4, 6), np.float32)
        self._threads = threads or _threads_allowed()
        # the first cast commits the scene: do it here, not in racing threads
        self.scene.cast_rays(o3d.core.Tensor(np.zeros((1, 6), np.float32)))

    def cast(self, pose: np.ndarray) -> Hits:
        """First hits of the camera's rays from a camera -> world pose (4x4)."""
        self._transform[0, :3] = pose[:3, 3]
        self._transform[1:, 3:] = pose[:3, :3].T
        rays = self._homogeneous @ self._transform
        ans = self.scene.cast_rays(self._o3d.core.Tensor.from_numpy(rays), nthreads=self._threads)
        # a miss has primitive id INVALID_ID (2**32 - 1): clamp it to the extra entry
        index = np.minimum(ans["primitive_ids"].numpy(), self._no_hit)
        cos_inc = np.einsum("ij,ij->i", ans["primitive_normals"].numpy(), rays[:, 3:])
        return Hits(
            t=ans["t_hit"].numpy().copy(),
            label=self._labels[index],
            cos_inc=np.abs(cos_inc),
            albedo=self._albedo[index],
        )


def draw_foot(
    hits: Hits, geometry: CameraGeometry, progress: float, strength: float, rng: np.random.Generator
) -> None:
    """The other foot and shank passing through the lower image, 0.25-0.45 m away."""
    w, h = geometry.width, geometry.height
    uc = w * rng.uniform(0.3, 0.55)
    vc = h * (1.25 - 0.5 * np.sin(np.pi * progress))  # enters from below and leaves again
    ru, rv = w * (0.12 + 0.12 * strength), h * (0.35 + 0.15 * strength)
    _draw_blob(hits, geometry, uc, vc, ru, rv, 0.25 + 0.2 * rng.random(), 0.08, 0.5)


def draw_occlusion(
    hits: Hits,
    rays_cam: np.ndarray,
    geometry: CameraGeometry,
    strength: float,
    rng: np.random.Generator,
) -> None:
    """Something flat close in front of the lens, over one side and the centre."""
    rays = rays_cam.reshape(geometry.height, geometry.width, 3)
    cols = np.arange(geometry.width)
    edge = geometry.width * (0.55 + 0.6 * strength)  # over the centre; half the time all
    covered = cols < edge if rng.random() < 0.5 else cols >= geometry.width - edge
    d0 = rng.uniform(0.3, 0.9)
    a, b = rng.uniform(-0.3, 0.3, size=2)  # the plane's tilt
    denom = rays[..., 2] - a * rays[..., 0] - b * rays[..., 1]
    t_occ = (d0 / np.maximum(denom, 0.2)).astype(np.float32)
    mask = np.broadcast_to(covered[None, :], t_occ.shape)
    _apply_occluder(hits, mask.ravel(), t_occ.ravel(), denom.ravel(), 0.6)


def draw_object(
    hits: Hits,
    rays_cam: np.ndarray,
    pose: np.ndarray,
    ground_z: float,
    strength: float,
    rng: np.random.Generator,
) -> None:
    """An object close ahead whose flat face fills the view: the other thigh, a bag, a
    door, a person passing. Its face is a plane across the whole view at a tilt a terrain
    could have (level, or a ramp's 5-15 degrees up or down), above the ground, so the
    image it leaves is a clean image of level ground or a ramp whatever the terrain."""
    rays = rays_cam @ pose[:3, :3].T  # world directions
    axis = pose[:3, 2]
    heading = np.arctan2(axis[1], axis[0])
    c, s = np.cos(heading), np.sin(heading)
    forward = rays[:, 0] * c + rays[:, 1] * s
    up = rays[:, 2]
    kind = rng.random()
    slope = 0.0 if kind < 0.4 else np.sign(kind - 0.7) * (5.0 + 10.0 * strength)
    k = np.tan(np.radians(slope + rng.normal(0.0, 1.0)))
    # its face: z = z0 + k x (camera at 0), above the ground over the view's 2.5 m
    z0 = ground_z - pose[2, 3] + 0.05 + 0.1 * rng.random() + max(0.0, -2.5 * k)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_obj = z0 / (up - k * forward)
    face = np.isfinite(t_obj) & (t_obj > 0.1)
    t_obj = np.where(face, t_obj, np.inf).astype(np.float32)
    cos_inc = (np.abs(up - k * forward) / np.sqrt(1 + k * k)).astype(np.float32)
    _apply_occluder(hits, face, t_obj, cos_inc, 0.45)


def _draw_blob(hits, geometry, uc, vc, ru, rv, depth, bulge, albedo) -> None:
    v, u = np.mgrid[0 : geometry.height, 0 : geometry.width]
    rho2 = ((u - uc) / ru) ** 2 + ((v - vc) / rv) ** 2
    mask = (rho2 < 1.0).ravel()
    t_occ = (depth + bulge * rho2).astype(np.float32).ravel()
    _apply_occluder(hits, mask, t_occ, np.sqrt(np.clip(1 - rho2, 0.05, 1)).ravel(), albedo)


def _apply_occluder(hits: Hits, mask, t_occ, cos_inc, albedo: float) -> None:
    front = mask & (t_occ < hits.t)
    hits.t[front] = t_occ[front]
    hits.label[front] = NOTHING
    hits.cos_inc[front] = cos_inc[front]
    hits.albedo[front] = albedo


def blend_swing(a: Hits, b: Hits, rng: np.random.Generator) -> Hits:
    """ToF motion artefacts: the phase images of one frame were taken at two poses.

    Where both poses see about the same depth the result is their mean (a cloud tilted
    halfway between the poses); where they disagree, pixels are lost or take either depth.
    """
    with np.errstate(invalid="ignore"):  # inf - inf where both missed
        close = np.abs(a.t - b.t) < 0.15 * a.t
    t = np.where(close, 0.5 * (a.t + b.t), a.t)
    u = rng.random(len(t), dtype=np.float32)
    far = ~close
    t = np.where(far & (u < 0.5), np.inf, t)
    t = np.where(far & (u >= 0.75), b.t, t).astype(np.float32)
    return Hits(t, a.label, np.minimum(a.cos_inc, b.cos_inc), a.albedo)


class ToFSensor:
    """What the ToF camera does to ideal depth (see the module docstring).

    Random draws come from pools made once, read at a random row offset per frame: drawing
    38k normals per frame would cost more than the rest of the model.
    """

    def __init__(self, geometry: CameraGeometry, params: ToFParams, seed: int = 0) -> None:
        self.geometry = geometry
        self.params = params
        self.rays_cam = geometry.rays().reshape(-1, 3)
        self.vignetting = (self.rays_cam[:, 2] ** 4).astype(np.float32)  # cos^4 law
        h, w = geometry.height, geometry.width
        pool = np.random.default_rng([seed, 99])
        # Noise as the adaptive filter leaves it: a 3 x 3 mean of white noise, rescaled.
        white = pool.standard_normal((3 * h + 2, w + 2), dtype=np.float32)
        smooth = sum(
            white[i : i + 3 * h, j : j + w] for i in range(3) for j in range(3)
        ) * np.float32(1 / 3)
        self._normal = smooth.ravel()
        self._white = pool.standard_normal(3 * h * w, dtype=np.float32)
        self._uniform = pool.random(3 * h * w, dtype=np.float32)

    def _draws(self, rng: np.random.Generator, pool: np.ndarray) -> np.ndarray:
        g = self.geometry
        offset = int(rng.integers(0, 2 * g.height)) * g.width  # whole rows: 2-D noise
        return pool[offset : offset + g.height * g.width]

    def apply(self, hits: Hits, rng: np.random.Generator, noise_scale: float = 1.0):
        """(xyz, confidence, gray) images of a frame, as the camera delivers them."""
        g, p = self.geometry, self.params
        h, w = g.height, g.width
        t = hits.t
        t_clamped = np.maximum(t, np.float32(0.1))
        amplitude = hits.albedo * hits.cos_inc
        amplitude *= self.vignetting
        amplitude /= np.square(t_clamped, out=t_clamped)  # 0 where nothing was hit (t = inf)
        valid = amplitude > p.min_amplitude
        valid &= hits.cos_inc > p.grazing_cos
        valid &= t <= g.max_range_m
        valid &= t >= g.min_range_m
        if p.speckle:
            valid &= self._draws(rng, self._uniform) >= p.speckle
        depth = np.where(valid, t, np.float32(0.0))
        mixed = self._mix_edges(depth, amplitude, valid, rng)

        sigma = p.noise_sigma(depth, amplitude).astype(np.float32)
        sigma *= np.float32(noise_scale)
        valid &= sigma <= p.max_noise_m
        depth += sigma * self._draws(rng, self._normal)
        depth *= valid
        valid &= ~self._flying(depth, valid)

        confidence = np.minimum(amplitude, p.full_amplitude)
        confidence *= 255.0 / p.full_amplitude
        confidence[mixed] *= 0.3
        depth *= valid  # invalid pixels: xyz = 0 and confidence 0, as royale delivers them
        xyz = self.rays_cam * depth[:, None]
        np.maximum(confidence, 1.0, out=confidence)
        confidence *= valid
        gray = amplitude * (3000.0 / p.full_amplitude)
        gray += self._draws(rng, self._white) * 4.0 + p.ambient_gray  # amplitude noise
        np.clip(gray, 0, 4095, out=gray)
        return (
            xyz.reshape(h, w, 3),
            confidence.astype(np.uint8).reshape(h, w),
            gray.astype(np.uint16).reshape(h, w),
        )

    def _mix_edges(
        self, depth: np.ndarray, amplitude: np.ndarray, valid: np.ndarray, rng
    ) -> np.ndarray:
        """Pixels beside a depth edge take in part of the neighbour's surface (their
        footprint straddles it): the depth measured is the amplitude-weighted mix. Changes
        `depth` in place; returns the mask of mixed pixels."""
        g, p = self.geometry, self.params
        h, w = g.height, g.width
        img = np.where(valid, depth, np.float32(np.nan)).reshape(h, w)
        # The largest jump to a neighbour, on every pixel (NaN beside an invalid one: fmax
        # passes it over); then, on the few edge pixels, which neighbour it is.
        across, down = np.abs(img[:, 1:] - img[:, :-1]), np.abs(img[1:] - img[:-1])
        largest = np.zeros((h, w), np.float32)
        for view, jumps in (
            (largest[:, 1:], across),
            (largest[:, :-1], across),
            (largest[1:], down),
            (largest[:-1], down),
        ):
            np.fmax(view, jumps, out=view)
        with np.errstate(invalid="ignore"):
            edge = np.flatnonzero(largest.ravel() > p.edge_jump_m + 0.03 * img.ravel())
        # each edge pixel's neighbour depth - own: left, right, up, down; the first of
        # equal jumps wins
        row, col = np.divmod(edge, w)
        flat = img.ravel()
        step = np.array([-1, 1, -w, w])
        inside = np.stack([col > 0, col < w - 1, row > 0, row < h - 1])
        neighbour = np.where(inside, edge + step[:, None], edge)
        jumps = np.where(inside, flat[neighbour] - flat[edge], np.float32(np.nan))
        side = np.nan_to_num(np.abs(jumps), nan=0.0).argmax(axis=0)
        pick = np.arange(len(edge))
        jump = jumps[side, pick]
        other = amplitude[neighbour[side, pick]]  # that neighbour's amplitude
        u = self._draws(rng, self._uniform)  # drawn whatever the edges: same later draws
        if len(edge):
            share = 0.5 * u[edge]  # of the footprint
            a_own = amplitude[edge]
            weight = share * other / np.maximum((1 - share) * a_own + share * other, 1e-9)
            depth[edge] += weight * jump
        mixed = np.zeros(len(depth), bool)
        mixed[edge] = True
        return mixed

    def _flying(self, depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """royale's flying-pixel flag on the final Z: a pixel differing from both of its
        left and right, or both of its upper and lower, neighbours by more than the
        threshold (an invalid neighbour flags nothing)."""
        g, p = self.geometry, self.params
        z = np.where(valid, depth * self.rays_cam[:, 2], np.float32(np.nan))
        z = z.reshape(g.height, g.width)
        threshold = p.flying_threshold(z)
        flag = np.zeros(z.shape, bool)
        with np.errstate(invalid="ignore"):
            c = z[:, 1:-1]
            lr = (np.abs(c - z[:, :-2]) > threshold[:, 1:-1]) & (
                np.abs(c - z[:, 2:]) > threshold[:, 1:-1]
            )
            flag[:, 1:-1] |= lr
            c = z[1:-1]
            ud = (np.abs(c - z[:-2]) > threshold[1:-1]) & (np.abs(c - z[2:]) > threshold[1:-1])
            flag[1:-1] |= ud
        return flag.ravel()
