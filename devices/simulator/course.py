"""Courses: the terrain a walker crosses, as segments along one straight walkway.

World frame (devices/frames.py): x forward along the course, y left, z up. The course
starts at x = 0 on ground at z = 0. Each segment covers [x0, x0 + length_m) and owns the
terrain profile z(x) there; the terrain is the same across y (a walkway wider than the
camera's view), outdoors with small bumps on top.

Stairs with n steps have n risers one tread apart, starting at x0; the last "tread" is the
floor they lead to, one tread deep. The default course is one trial of the paper: three
level-ground segments and one each of up stairs, up ramp, down ramp, down stairs
(LG US UR LG DR DS LG: ascents meet ascents, descents meet descents, as the paper's
transition matrix suggests). Where a custom order turns from going up to going down (or
back), a level landing (LANDING_M) is inserted as its own LG segment: it is level ground.
Presets: "indoor" and "outdoor", randomised by a seed: risers 0.10-0.20 m, treads
0.25-0.38 m (the authors' stairs, risers 0.15 +- 0.05 m and treads 0.33 +- 0.05 m, lie
inside), ramps 5-15 degrees; outdoors also curbs (one-step height changes inside
level-ground segments), uneven ground and clutter beside the walkway.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from devices.frames import MODES

PRESETS = ("indoor", "outdoor")
RISER_M = (0.10, 0.20)  # stairs' riser height and tread depth, drawn per staircase
TREAD_M = (0.25, 0.38)
# One trial of the paper: three level-ground segments, one of each other mode.
PAPER_TRIAL = ("LG", "US", "UR", "LG", "DR", "DS", "LG")
ASCENTS, DESCENTS = ("US", "UR"), ("DS", "DR")
# Uneven ground outdoors: 1 cm RMS of height in waves 1-3 m long. A walkway is level
# ground while its running slope stays within 1:20 (2.9 deg; steeper is a ramp: ADA 2010
# Standards 403.3, 405.2): over 0.3 m these waves exceed it in about 5 % of places, over
# 1 m in 1 %.
BUMP_RMS_M = 0.010
# A landing where going up turns into going down: at least 60 in (1.525 m) long, as a ramp
# landing must be (ADA 2010 Standards 405.7.3).
LANDING_M = (1.525, 2.0)
BUMP_WAVELENGTH_M = (1.0, 3.0)


@dataclass(frozen=True)
class Segment:
    mode: str  # one of MODES
    x0: float  # start along the course, metres
    z0: float  # ground height at the start
    length_m: float
    steps: int = 0  # stairs
    riser_m: float = 0.0
    tread_m: float = 0.0
    slope_deg: float = 0.0  # ramps, magnitude; the mode says up or down
    curbs: tuple[tuple[float, float], ...] = ()  # level ground: (x, height change)

    @property
    def x1(self) -> float:
        return self.x0 + self.length_m

    @property
    def rise_m(self) -> float:
        """Height change from start to end (negative going down)."""
        sign = -1.0 if self.mode in DESCENTS else 1.0
        if self.mode in ("US", "DS"):
            return sign * self.steps * self.riser_m
        if self.mode in ("UR", "DR"):
            return sign * self.length_m * float(np.tan(np.radians(self.slope_deg)))
        return float(sum(dz for _, dz in self.curbs))

    @property
    def z1(self) -> float:
        return self.z0 + self.rise_m

    def height_at(self, x: np.ndarray) -> np.ndarray:
        """Ground height at course positions x (inside or at the ends of the segment)."""
        x = np.asarray(x, dtype=np.float64)
        d = np.clip(x - self.x0, 0.0, self.length_m)
        if self.mode in ("US", "DS"):
            sign = 1.0 if self.mode == "US" else -1.0
            k = np.minimum(np.floor(d / self.tread_m) + 1, self.steps)
            return self.z0 + sign * k * self.riser_m
        if self.mode in ("UR", "DR"):
            sign = 1.0 if self.mode == "UR" else -1.0
            return self.z0 + sign * d * np.tan(np.radians(self.slope_deg))
        z = np.full_like(d, self.z0)
        for cx, dz in self.curbs:
            z = z + np.where(x >= cx, dz, 0.0)
        return z

    def profile(self) -> np.ndarray:
        """Corners of the profile, (n, 2) of (x, z); a riser is two corners at one x."""
        pts = [(self.x0, self.z0)]
        if self.mode in ("US", "DS"):
            sign = 1.0 if self.mode == "US" else -1.0
            z = self.z0
            for k in range(self.steps):
                x = self.x0 + k * self.tread_m
                pts.append((x, z + sign * self.riser_m))
                z += sign * self.riser_m
                if k + 1 < self.steps:
                    pts.append((x + self.tread_m, z))
        elif self.mode == "LG":
            z = self.z0
            for cx, dz in sorted(self.curbs):
                pts += [(cx, z), (cx, z + dz)]
                z += dz
        pts.append((self.x1, self.z1))
        return np.array(pts, dtype=np.float64)


@dataclass(frozen=True)
class Box:
    """An axis-aligned obstacle (clutter beside the walkway, a wall): centre and size."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]


@dataclass(frozen=True)
class Course:
    segments: tuple[Segment, ...]
    preset: str = "indoor"
    seed: int = 0
    half_width_m: float = 3.0  # terrain extends this far either side of the centre line
    bump_m: float = 0.0  # RMS height of uneven ground (outdoors)
    boxes: tuple[Box, ...] = ()  # walls and clutter
    bump_waves: tuple[tuple[float, float, float, float], ...] = field(default=(), repr=False)

    @property
    def length_m(self) -> float:
        return self.segments[-1].x1 - self.segments[0].x0

    @property
    def outdoor(self) -> bool:
        return self.preset == "outdoor"

    @property
    def modes(self) -> tuple[str, ...]:
        return tuple(s.mode for s in self.segments)

    @cached_property
    def _starts(self) -> np.ndarray:
        return np.array([s.x0 for s in self.segments])

    def segment_index(self, x: np.ndarray | float) -> np.ndarray:
        """Index of the segment at course positions x (clamped to the first/last one)."""
        i = np.searchsorted(self._starts, x, side="right") - 1
        return np.clip(i, 0, len(self.segments) - 1)

    def mode_at(self, x: float) -> str:
        return self.segments[int(self.segment_index(x))].mode

    def height_at(self, x: np.ndarray | float) -> np.ndarray:
        """Ground height along the centre line (level before the start and after the end)."""
        x = np.asarray(x, dtype=np.float64)
        idx = self.segment_index(x)
        z = np.empty_like(x)
        for i, seg in enumerate(self.segments):
            sel = idx == i
            if np.any(sel):
                z[sel] = seg.height_at(x[sel])
        return z

    def bumps(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Uneven ground: a smooth random surface of amplitude bump_m (zero indoors)."""
        z = np.zeros(np.broadcast(x, y).shape)
        for kx, ky, phase, amp in self.bump_waves:
            z += amp * np.sin(kx * x + ky * y + phase)
        return z


def _stairs(
    mode: str, x0: float, z0: float, rng: np.random.Generator, steps: tuple[int, int]
) -> Segment:
    n = int(rng.integers(steps[0], steps[1] + 1))
    riser = float(rng.uniform(*RISER_M))
    tread = float(rng.uniform(*TREAD_M))
    return Segment(mode, x0, z0, n * tread, steps=n, riser_m=riser, tread_m=tread)


def _ramp(mode: str, x0: float, z0: float, rng: np.random.Generator) -> Segment:
    return Segment(
        mode, x0, z0, float(rng.uniform(3.0, 5.0)), slope_deg=float(rng.uniform(5.0, 15.0))
    )


def _level(x0: float, z0: float, rng: np.random.Generator, outdoor: bool) -> Segment:
    length = float(rng.uniform(3.0, 5.0))
    curbs: tuple[tuple[float, float], ...] = ()
    if outdoor and rng.random() < 0.7:  # a curb up or down, away from the ends
        dz = float(rng.uniform(0.08, 0.15) * rng.choice([-1.0, 1.0]))
        curbs = ((x0 + float(rng.uniform(1.2, length - 1.2)), dz),)
    return Segment("LG", x0, z0, length, curbs=curbs)


def make_course(
    preset: str = "indoor", seed: int = 0, modes: tuple[str, ...] | list[str] | None = None
) -> Course:
    """A course for a preset and seed; `modes` (default: one trial of the paper) orders it."""
    if preset not in PRESETS:
        raise ValueError(f"unknown course preset {preset!r} (known: {', '.join(PRESETS)})")
    modes = tuple(modes) if modes else PAPER_TRIAL
    unknown = [m for m in modes if m not in MODES]
    if unknown:
        raise ValueError(f"unknown mode {unknown[0]!r} (known: {', '.join(MODES)})")
    outdoor = preset == "outdoor"
    rng = np.random.default_rng([seed, PRESETS.index(preset)])
    segments: list[Segment] = []
    x, z = 0.0, 0.0
    steps = (3, 7) if outdoor else (4, 6)
    for i, mode in enumerate(modes):
        if i > 0 and _turns(modes[i - 1], mode):
            segments.append(Segment("LG", x, z, float(rng.uniform(*LANDING_M))))
            x = segments[-1].x1
        if mode == "LG":
            seg = _level(x, z, rng, outdoor)
        elif mode in ("US", "DS"):
            seg = _stairs(mode, x, z, rng, steps)
        else:
            seg = _ramp(mode, x, z, rng)
        segments.append(seg)
        x, z = seg.x1, seg.z1
    bare = Course(tuple(segments), preset, seed)
    if outdoor:
        return Course(
            bare.segments,
            preset,
            seed,
            bump_m=BUMP_RMS_M,
            boxes=tuple(_clutter(bare, rng)),
            bump_waves=tuple(_bump_waves(rng, BUMP_RMS_M)),
        )
    return Course(bare.segments, preset, seed, boxes=tuple(_walls(bare, rng)))


def _turns(before: str, after: str) -> bool:
    """Going up turns into going down or back: a landing must join them."""
    return (before in ASCENTS and after in DESCENTS) or (before in DESCENTS and after in ASCENTS)


def _bump_waves(rng: np.random.Generator, amplitude: float):
    """Six plane waves of BUMP_WAVELENGTH_M whose sum has an RMS of `amplitude`."""
    n = 6
    for _ in range(n):
        k = 2 * np.pi / rng.uniform(*BUMP_WAVELENGTH_M)
        angle = rng.uniform(0, np.pi)
        yield (
            float(k * np.cos(angle)),
            float(k * np.sin(angle)),
            float(rng.uniform(0, 2 * np.pi)),
            float(amplitude / np.sqrt(n / 2)),
        )


def _walls(course: Course, rng: np.random.Generator):
    """Indoor corridor walls either side, 2.0-3.0 m apart, high enough for every level."""
    half = float(rng.uniform(1.0, 1.5))
    heights = course.height_at(np.linspace(0, course.length_m, 200))
    lo, hi = float(heights.min()) - 0.5, float(heights.max()) + 2.5
    x0, x1 = -3.0, course.length_m + 6.0
    for y in (-half - 0.05, half + 0.05):
        yield Box(((x0 + x1) / 2, y, (lo + hi) / 2), (x1 - x0, 0.1, hi - lo))


def _clutter(course: Course, rng: np.random.Generator):
    """Bins, posts, bushes and parked things beside the walkway, one every ~1.5 m a side."""
    x = -1.0
    while x < course.length_m + 4.0:
        x += float(rng.uniform(0.8, 2.2))
        side = float(rng.choice([-1.0, 1.0]))
        y = side * float(rng.uniform(0.75, 2.5))
        size = (
            float(rng.uniform(0.1, 0.8)),
            float(rng.uniform(0.1, 0.8)),
            float(rng.uniform(0.2, 1.5)),
        )
        ground = float(course.height_at(np.array([x]))[0])
        yield Box((x, y, ground + size[2] / 2 - 0.02), size)
