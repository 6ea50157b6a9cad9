"""Rendering: ray casting the course with Open3D, then what a ToF camera does to depth.

`TerrainScene` builds the course's triangle mesh and Open3D's RaycastingScene once and
casts one ray per pixel (camera rays precomputed once). The ToF model (`ToFSensor`):
- range-dependent noise: sigma = 1 % of the range, more where the returned amplitude
  (albedo * cos(incidence) * vignetting / range^2) is low, more outdoors (sunlight);
- invalid pixels: beyond 0.1-4 m, at grazing incidence, too little amplitude; outdoors
  also a speckle of saturated pixels;
- flying pixels at depth edges: most are filtered out (confidence 0, as royale's filter
  does), the rest float between foreground and background with low confidence;
- confidence from amplitude (1-255, 0 = invalid), gray value = amplitude; invalid pixels
  have xyz = 0 and confidence 0, exactly like royale frames.
Occluders for error images (the other foot, something in front of the lens) are drawn
analytically in the camera frame, so the scene never changes per frame.
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


@dataclass(frozen=True)
class ToFParams:
    noise_rel: float = 0.01  # depth noise sigma / range at full amplitude
    min_amplitude: float = 0.006  # below: invalid (too dark, too far, too grazing)
    full_amplitude: float = 0.25  # amplitude of a good return (albedo 0.5 at 1.4 m)
    grazing_cos: float = 0.10  # incidence beyond ~84 degrees: invalid
    flying_jump_m: float = 0.04  # a depth edge: neighbours differ by this + 3 % of range
    flying_filtered: float = 0.65  # share of edge pixels the camera's filter invalidates
    speckle: float = 0.0  # share of random invalid pixels (sunlight)
    ambient_gray: float = 30.0

    @classmethod
    def for_course(cls, course: Course) -> ToFParams:
        if course.outdoor:
            return cls(noise_rel=0.016, min_amplitude=0.009, speckle=0.01, ambient_gray=250.0)
        return cls()


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
    """OMP_NUM_THREADS when it is a positive integer, else 0 (all cores)."""
    text = os.environ.get("OMP_NUM_THREADS", "")
    return int(text) if text.isdigit() else 0


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
    edge = geometry.width * (0.55 + 0.3 * strength)  # always over the centre
    covered = cols < edge if rng.random() < 0.5 else cols >= geometry.width - edge
    d0 = rng.uniform(0.3, 0.9)
    a, b = rng.uniform(-0.3, 0.3, size=2)  # the plane's tilt
    denom = rays[..., 2] - a * rays[..., 0] - b * rays[..., 1]
    t_occ = (d0 / np.maximum(denom, 0.2)).astype(np.float32)
    mask = np.broadcast_to(covered[None, :], t_occ.shape)
    _apply_occluder(hits, mask.ravel(), t_occ.ravel(), denom.ravel(), 0.6)


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

    Random draws come from pools made once, read at a random offset per frame: drawing
    38k normals per frame would cost more than the rest of the model.
    """

    def __init__(self, geometry: CameraGeometry, params: ToFParams, seed: int = 0) -> None:
        self.geometry = geometry
        self.params = params
        self.rays_cam = geometry.rays().reshape(-1, 3)
        self.vignetting = (self.rays_cam[:, 2] ** 4).astype(np.float32)  # cos^4 law
        n = len(self.rays_cam)
        pool = np.random.default_rng([seed, 99])
        self._normal = pool.standard_normal(3 * n, dtype=np.float32)
        self._uniform = pool.random(3 * n, dtype=np.float32)

    def _draws(self, rng: np.random.Generator, pool: np.ndarray) -> np.ndarray:
        n = len(self.rays_cam)
        offset = int(rng.integers(0, 2 * n))
        return pool[offset : offset + n]

    def apply(self, hits: Hits, rng: np.random.Generator, noise_scale: float = 1.0):
        """(xyz, confidence, gray) images of a frame, as the camera delivers them."""
        g, p = self.geometry, self.params
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
        normal = self._draws(rng, self._normal)
        # sigma = noise_rel * range / sqrt(relative amplitude), the amplitude floored at 10 %
        noise = np.clip(amplitude, 0.1 * p.full_amplitude, p.full_amplitude)
        np.sqrt(noise, out=noise)
        depth = np.where(valid, t, np.float32(0.0))
        np.divide(depth, noise, out=noise)
        noise *= normal
        noise *= np.float32(p.noise_rel * noise_scale * np.sqrt(p.full_amplitude))
        depth += noise
        confidence = np.minimum(amplitude, p.full_amplitude)
        confidence *= 255.0 / p.full_amplitude

        # flying pixels: a pixel beside a much nearer neighbour mixes both depths
        img = np.where(valid, t, np.float32(np.nan)).reshape(g.height, g.width)
        nearest = np.full_like(img, np.nan)
        for a, b in (
            ((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
            ((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
        ):
            np.fmin(nearest[a], img[b], out=nearest[a])
            np.fmin(nearest[b], img[a], out=nearest[b])
        with np.errstate(invalid="ignore"):
            nearest -= img
            edge = np.flatnonzero(nearest < -(p.flying_jump_m + 0.03 * img))
        if len(edge):
            u = self._draws(rng, self._uniform)[edge]
            valid[edge[u < p.flying_filtered]] = False
            flying = edge[u >= p.flying_filtered]
            mix = 0.2 + 0.6 * self._draws(rng, self._uniform)[flying]
            depth[flying] += mix * nearest.ravel()[flying]
            confidence[flying] *= 0.2

        depth *= valid  # invalid pixels: xyz = 0 and confidence 0, as royale delivers them
        xyz = self.rays_cam * depth[:, None]
        np.maximum(confidence, 1.0, out=confidence)
        confidence *= valid
        gray = amplitude * (3000.0 / p.full_amplitude)
        gray += normal * 4.0 + p.ambient_gray  # amplitude noise, reusing the draws
        np.clip(gray, 0, 4095, out=gray)
        h, w = g.height, g.width
        return (
            xyz.reshape(h, w, 3),
            confidence.astype(np.uint8).reshape(h, w),
            gray.astype(np.uint16).reshape(h, w),
        )
