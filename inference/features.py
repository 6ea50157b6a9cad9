"""Terrain features from the leveled sagittal profile: ramp slope, stair riser and tread.

After the authors' earlier work (Zhang et al. 2019): ramp slope from a line fit along the
median-filtered profile, riser height from the difference of tread levels, tread depth
from the distance between consecutive stair edges.

How: the camera sees every point of the profile along its own ray, so the visible terrain
is a function of the elevation angle seen from the camera (origin of the profile). The
profile is cut into thin angle bins, each reduced to its median range (this is the median
filter; the noise of a time-of-flight camera is along the ray), giving an ordered
polyline from near to far. Range jumps (occlusions: the nosing of a step going down)
break it; split-and-merge cuts it into straight segments; each segment is refit on its
raw points by least squares along the rays (trimmed), where the camera's noise lies: a
perpendicular fit would tilt far level ground down. Then:
- stairs: consecutive horizontal segments (treads) whose levels differ by a riser height,
  all in the same direction; riser = median level difference; tread depth = median
  distance between consecutive stair edges (up: the riser's position; down: the far end
  of the upper tread, where it drops), when at least two edges are seen;
- ramp: a long slanted segment; slope = its angle, positive uphill;
- level: mostly horizontal segments; slope reported too (near 0), the tilt of the level
  ground the frame shows: one line along the rays through each stretch of level ground
  (its flat pieces and the short noisy ones between them), the stretches' angles averaged
  by their precision (a curb splits level ground, not its tilt); None where that tilt is
  uncertain by more than LEVEL_SLOPE_MAX_SE_DEG. When the fused decision says level
  ground, level wins over a ramp while the ground a step ahead (AHEAD_M) is flat or flat
  pieces fill more of the image than the ramp: the image's terrain is the one filling
  most of it, so a ramp or stairs beginning inside it do not yet set the slope;
- unknown: anything else (too few points, clutter).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from devices.frames import MODES

ANGLE_BIN_DEG = 0.4  # polyline resolution (about 7 mm at 1 m)
MIN_BIN_POINTS = 2
BREAK_GAP_M = 0.08  # a range jump larger than this between neighbouring bins: occlusion
JUMP_RATIO, JUMP_WINDOW = 3.0, 3  # ...and this many times the steps 3 either side
# Neighbouring segments merge when one line leaves at most this times their two lines'
# squared residuals (the noise is correlated over ~3 x 3 pixels: fewer independent points
# than an F test would count) and keeps this share of their points.
MERGE_RSS_RATIO, MERGE_MIN_KEPT = 1.3, 0.95
SPLIT_TOL_M = 0.015  # split-and-merge tolerance
FIT_TRIM_M = 0.025  # points farther than this from a segment's line are not its own
FLAT_MAX_DEG = 3.0  # a segment this close to horizontal is flat (a tread, level ground)
FLAT_SE = 2.0  # ...or closer than this many standard errors of its angle (angle_se_deg)
NOISE_CELL_POINTS = 9  # the range noise is correlated over about 3 x 3 pixels
FLAT_SHORT_RISE_M = 0.015  # ...or a short one that rises less than this end to end
FLAT_SHORT_MAX_DEG = 12.0
MIN_ANGLE_SE_DEG = 0.05  # a level slope's weights: no piece's angle is surer than this
LEVEL_SLOPE_MAX_SE_DEG = 1.5  # a level slope less sure than this (one SE) is not reported
RAMP_MAX_DEG = 35.0
RAMP_MIN_LENGTH_M = 0.25  # 0.15 when the fused decision says ramp
RISER_MIN_M = 0.04
RISER_MAX_M = 0.30
TREAD_MIN_M = 0.10
TREAD_MAX_M = 0.80
MAX_HIDDEN_M = 0.6  # longest occluded stretch between two treads going down
MIN_POINTS = 30
# The preprocessing's forward cut (PreprocessConfig.max_forward_m's default), and how near
# it a point marks its ray as cut (the range noise along x at 2.5 m is about 5 cm).
MAX_FORWARD_M = 2.5
CUT_MARGIN_M = 0.08
# Where the classifier's terrain is judged: about a step ahead of the camera (the images are
# labelled with the terrain they show there; the simulator's truth looks 0.6-1.1 m ahead).
AHEAD_M = 1.0
IMAGE_REACH_M = 0.99  # the image's forward reach from the nearest point (preprocess.rasterise)


@dataclass
class TerrainFeatures:
    kind: str = "unknown"  # ramp | stairs | level | unknown
    slope_deg: float | None = None  # positive uphill (ramp, level)
    riser_m: float | None = None  # stairs: step height (positive)
    tread_m: float | None = None  # stairs: step depth, when two stair edges are seen
    direction: str = ""  # "up" | "down" for ramps and stairs
    steps: int = 0  # risers seen
    ahead_slope_deg: float | None = None  # the fitted ground AHEAD_M ahead, positive uphill
    inlier_fraction: float = 0.0  # profile points explained by the fitted segments
    residual_m: float | None = None  # RMS distance of those points to their segments
    segments: list = field(default_factory=list)  # [(x0, z0, x1, z1, angle_deg), ...]
    # Where the terrain ahead changes, forward from the camera (m; None: not seen): the
    # first riser up, the first drop (a nosing), the start of a ramp up or down, the start
    # of level ground after stairs or a ramp (terrain_edges).
    edge_rise_m: float | None = None
    edge_drop_m: float | None = None
    edge_ramp_up_m: float | None = None
    edge_ramp_down_m: float | None = None
    edge_level_m: float | None = None


@dataclass(eq=False)
class _Segment:
    profile: np.ndarray | None  # (M, 2) the sorted profile (None: left behind, drop_points)
    index: np.ndarray | None  # the indices of its own points in it
    start: np.ndarray  # (x, z), near end (a pair of floats once drop_points has run)
    end: np.ndarray  # far end
    angle_deg: float  # of the travel direction near -> far: +90 riser up, 0 flat
    centre: np.ndarray
    rms_m: float
    first: int = 0  # the slice of the sorted profile it was fitted on
    stop: int = 0

    @functools.cached_property
    def points(self) -> np.ndarray:
        """(K, 2) the profile's points that are its own."""
        return self.profile[self.index]

    @functools.cached_property
    def count(self) -> int:
        """How many points are its own."""
        return len(self.index)

    @property
    def rss(self) -> float:
        """Sum of its points' squared distances to the line."""
        return self.rms_m**2 * self.count

    @functools.cached_property
    def length(self) -> float:
        return float(np.hypot(*(self.end - self.start)))

    @property
    def angle_se_deg(self) -> float:
        """Standard error of angle_deg: the residuals over the spread of its points along
        the line, with one independent point per NOISE_CELL_POINTS (correlated noise)."""
        independent = max(self.count / NOISE_CELL_POINTS, 2.0)
        spread = max(self.length, 1e-6) * math.sqrt(independent / 12.0)
        return math.degrees(self.rms_m / spread)

    @functools.cached_property
    def flat(self) -> bool:
        """Horizontal, or not measurably sloped: a far stretch whose angle the noise
        leaves uncertain by degrees is no evidence of a ramp."""
        rise = abs(float(self.end[1] - self.start[1]))
        if abs(self.angle_deg) <= FLAT_MAX_DEG:
            return True
        return abs(self.angle_deg) <= FLAT_SHORT_MAX_DEG and (
            rise <= FLAT_SHORT_RISE_M
            or abs(self.angle_deg) <= FLAT_MAX_DEG + FLAT_SE * self.angle_se_deg
        )

    # The order statistics of its points (the compiled fit works them out with the line).
    @functools.cached_property
    def level(self) -> float:
        """The median height of its points."""
        return float(np.median(self.points[:, 1]))

    @functools.cached_property
    def x_p2(self) -> float:
        """The 2nd percentile of its points' forward distances: where it begins."""
        return float(np.percentile(self.points[:, 0], 2))

    @functools.cached_property
    def x_median(self) -> float:
        return float(np.median(self.points[:, 0]))

    @functools.cached_property
    def x_p98(self) -> float:
        """The 98th percentile of its points' forward distances: where it ends."""
        return float(np.percentile(self.points[:, 0], 98))

    def drop_points(self) -> None:
        """Its points left behind, for another process: what the classification reads (its
        figures and order statistics) worked out first, its ends made float pairs. A level
        stretch of one segment is that segment: a second call finds it done."""
        if self.profile is None:
            return
        for name in ("count", "length", "flat", "level", "x_p2", "x_median", "x_p98"):
            getattr(self, name)
        self.profile = self.index = self.centre = None
        self.start, self.end = tuple(self.start.tolist()), tuple(self.end.tolist())
        vars(self).pop("points", None)


def terrain_features(
    profile: np.ndarray,
    mode_hint: str | None = None,
    max_forward_m: float = MAX_FORWARD_M,
    *,
    fit: ProfileFit | None = None,
) -> TerrainFeatures:
    """Features of the leveled profile ((M, 2): forward x, height z, camera at the origin).

    mode_hint: the fused decision ("LG", "US", "DS", "UR", "DR") or None; it only relaxes
    the evidence needed for the matching kind. max_forward_m: where the preprocessing cut
    the profile (PreprocessConfig.max_forward_m). fit: fit_profile() of the profile when
    worked out already (replay does it in its reader process; `profile` is then unused).
    """
    return classify(fit if fit is not None else fit_profile(profile, max_forward_m), mode_hint)


@dataclass
class ProfileFit:
    """What a profile shows whatever the fused decision: its segments near to far, how
    well they explain it, the edges ahead, the ground's slope a step ahead and the level
    stretches' lines (_level_stretches). classify() reads only these; the segments serve
    it as well once `drop_points()` has left their points behind, at a fraction of the
    bytes."""

    segments: list[_Segment] = field(default_factory=list)
    x_near: float = 0.0  # the nearest point's forward distance
    inlier_fraction: float = 0.0
    residual_m: float | None = None
    edges: dict = field(default_factory=dict)  # terrain_edges()
    ahead_slope_deg: float | None = None
    stretches: list[_Segment] = field(default_factory=list)

    def drop_points(self) -> ProfileFit:
        """This fit, its segments' and stretches' points left behind (_Segment.drop_points)."""
        for segment in (*self.segments, *self.stretches):
            segment.drop_points()
        return self


def fit_profile(
    profile: np.ndarray, max_forward_m: float = MAX_FORWARD_M, compiled: bool = True
) -> ProfileFit:
    """The hint-free part of terrain_features: the profile's segments and what follows
    from them alone. compiled False: the straightforward numpy functions below (the
    reference inference.profile_fit is tested against) cut and fit the segments."""
    pts = np.asarray(profile, dtype=np.float64).reshape(-1, 2)
    x, z = pts[:, 0], pts[:, 1]
    keep = (x > 0) & (x < np.inf) & np.isfinite(z)  # per column: all(axis=1) costs more
    x, z = x[keep], z[keep]
    if len(x) < MIN_POINTS:
        return ProfileFit()
    bins = np.floor(np.arctan2(z, x) * (1.0 / np.radians(ANGLE_BIN_DEG))).astype(np.int64)
    if compiled:
        return _compiled_profile_fit(x, z, bins, max_forward_m)
    rng = np.sqrt(x * x + z * z)
    # A ray the forward cut crosses kept only its nearer points (the range noise runs along
    # the ray): its median is too near, too high on far level ground. Such rays go whole.
    cut = x > max_forward_m - CUT_MARGIN_M
    if cut.any():
        keep = ~np.isin(bins, np.unique(bins[cut]))
        x, z, rng, bins = x[keep], z[keep], rng[keep], bins[keep]
        if len(x) < MIN_POINTS:
            return ProfileFit()
    # Sorted by angle bin, then by range within the bin (ranges < 100 m): the polyline's
    # medians are the middle of each bin, and a segment's own points are one slice.
    order = np.argsort(bins * 128.0 + np.minimum(rng, 100.0), kind="stable")
    pts = np.column_stack((x[order], z[order]))
    bins, rng = bins[order], rng[order]
    segments = [s for run in _polyline_runs(bins, rng) for s in _fit_segments(run, pts, bins)]
    return _profile_fit(segments, len(pts), float(x.min()), _fit_points)


def _profile_fit(segments: list[_Segment], points: int, x_near: float, refit) -> ProfileFit:
    """The ProfileFit of `segments` of a sorted profile of so many `points`; `refit` as
    _level_stretches takes it."""
    if not segments:
        return ProfileFit()
    explained = np.zeros(points, bool)
    for s in segments:
        explained[s.index] = True
    return ProfileFit(
        segments=segments,
        x_near=x_near,
        inlier_fraction=float(explained.mean()),
        residual_m=float(
            np.sqrt(sum(s.rms_m**2 * s.count for s in segments) / sum(s.count for s in segments))
        ),
        edges=terrain_edges(segments),
        ahead_slope_deg=_slope_at(segments, AHEAD_M),
        stretches=_level_stretches(segments, refit),
    )


def classify(fit: ProfileFit, mode_hint: str | None = None) -> TerrainFeatures:
    """The features of a fitted profile under the fused decision `mode_hint`."""
    segments = fit.segments
    if not segments:
        return TerrainFeatures()
    # A fused decision of level ground keeps the frame level while the ground a step ahead
    # (AHEAD_M) is flat, or flat pieces fill more of the image than a ramp, or make up most
    # of what is seen: a slanted piece beyond or starting inside the image (the next terrain
    # coming into view, or a far stretch the noise tilts) is not yet the ground it shows.
    result = (
        _stairs(segments, mode_hint)
        or (mode_hint == "LG" and _level(fit, _level_shown(segments, fit.x_near)))
        or _ramp(segments, mode_hint)
        or _level(fit)
        or TerrainFeatures()
    )
    result.ahead_slope_deg = fit.ahead_slope_deg
    for name, x_m in fit.edges.items():
        setattr(result, f"edge_{name}_m", x_m)
    result.inlier_fraction = fit.inlier_fraction
    result.residual_m = fit.residual_m
    result.segments = [
        (float(s.start[0]), float(s.start[1]), float(s.end[0]), float(s.end[1]), float(s.angle_deg))
        for s in segments
    ]
    return result


def _compiled_profile_fit(x, z, bins, max_forward_m: float) -> ProfileFit:
    """fit_profile by inference.profile_fit, from the points kept and their angle bins."""
    from inference import profile_fit as pf

    xs, zs, bins, _, x_near, medians = pf.sorted_profile(x, z, bins, max_forward_m - CUT_MARGIN_M)
    if len(xs) < MIN_POINTS:
        return ProfileFit()
    table, members = pf.segments(
        xs,
        zs,
        bins,
        medians,
        np.radians(ANGLE_BIN_DEG),
        MIN_BIN_POINTS,
        BREAK_GAP_M,
        JUMP_RATIO,
        JUMP_WINDOW,
        SPLIT_TOL_M,
        FIT_TRIM_M,
        MERGE_RSS_RATIO,
        MERGE_MIN_KEPT,
    )
    pts = np.column_stack((xs, zs))
    segments, at = [], 0
    for row in table:
        count = int(row[pf.COUNT])
        segments.append(_table_segment(row, pts, members[at : at + count]))
        at += count
    return _profile_fit(segments, len(pts), x_near, _compiled_fit)


def _compiled_fit(pts: np.ndarray, index: np.ndarray) -> _Segment | None:
    """_fit_points on the points `index` of the sorted profile, by inference.profile_fit."""
    from inference import profile_fit as pf

    row, kept = pf.fit_points(pts[:, 0], pts[:, 1], index, FIT_TRIM_M)
    return _table_segment(row[0], pts, kept) if len(row) else None


def _table_segment(row: np.ndarray, pts: np.ndarray, index: np.ndarray) -> _Segment:
    """A row of inference.profile_fit's segment table as a _Segment of the sorted profile
    `pts`, its order statistics known."""
    from inference import profile_fit as pf

    seg = _Segment(
        profile=pts,
        index=index,
        start=row[pf.START_X : pf.START_Z + 1],
        end=row[pf.END_X : pf.END_Z + 1],
        angle_deg=float(row[pf.ANGLE]),
        centre=row[pf.CENTRE_X : pf.CENTRE_Z + 1],
        rms_m=float(row[pf.RMS]),
        first=int(row[pf.FIRST]),
        stop=int(row[pf.STOP]),
    )
    # the cached properties, worked out already
    vars(seg).update(
        level=float(row[pf.LEVEL]),
        x_p2=float(row[pf.X_P2]),
        x_median=float(row[pf.X_MEDIAN]),
        x_p98=float(row[pf.X_P98]),
    )
    return seg


# Edges: a riser is a steep piece rising more than RISER_MIN_M above the ground before it
# (or a tread that much higher); level ground after stairs or a ramp is a flat stretch longer
# than any tread (TREAD_MAX_M would take a landing for a tread: 0.45 m is the longest tread
# the courses and the codes allow, 0.38 m, with a margin).
RISER_STEEP_DEG = 45.0
LEVEL_RUN_M = 0.45
# Seen from above, a flight of stairs down hides its treads behind the nosings: the next
# surface seen may lie far beyond the edge (a riser of 0.2 m hides 2 m of treads from a
# camera 0.5 m up, 1 m before the edge), or the nosings line up as one steep slope, steeper
# than the 15 degrees of the courses' steepest ramp (the codes allow 7).
MAX_DROP_GAP_M = 2.0
FLIGHT_MIN_DEG = 20.0
EDGES = ("rise", "drop", "ramp_up", "ramp_down", "level")


def terrain_edges(segments: list[_Segment]) -> dict[str, float | None]:
    """Forward distance (m) of the first place along the profile, near to far, where the
    terrain changes, by kind (EDGES): where the walker's foot would meet the next terrain.
    Distances are along the ground from the camera (at 0); None: not in view.

    - rise: a riser up (a steep piece, or the next surface starting a riser higher);
    - drop: a nosing (the next surface a riser lower, its start hidden by the edge);
    - ramp_up, ramp_down: the start of a slanted stretch at least RAMP_MIN_LENGTH_M long;
    - level: the start of flat ground longer than any tread after stairs or a ramp (the
      top or bottom riser's edge, or a ramp's end).
    """
    found: dict[str, float | None] = dict.fromkeys(EDGES)
    surface: _Segment | None = None  # the last surface passed (flat or a ramp)
    changed = False  # stairs or a ramp lie between the near ground and here

    def first(kind: str, x_m: float) -> None:
        if found[kind] is None:
            found[kind] = float(x_m)

    for s in segments:
        x0 = float(min(s.start[0], s.end[0]))
        steep = abs(s.angle_deg) > RISER_STEEP_DEG
        if steep:
            if s.length >= 0.03 and s.angle_deg > 0:
                top = float(max(s.start[1], s.end[1]))
                base = surface.end[1] if surface is not None else min(s.start[1], s.end[1])
                if top - float(base) >= RISER_MIN_M:
                    first("rise", s.x_median)
                    changed = True
            continue
        if surface is not None:
            step = float(s.start[1] - surface.end[1])  # height change at the junction
            gap = s.x_p2 - surface.x_p98
            if step >= RISER_MIN_M and gap <= 0.05:
                first("rise", x0)
                changed = True
            elif step <= -RISER_MIN_M and -0.02 <= gap <= MAX_DROP_GAP_M:
                edge = _nosing(surface, s)
                first("drop", edge)
                changed = True
                if s.flat and s.length >= LEVEL_RUN_M and -step <= RISER_MAX_M:
                    first("level", edge)  # one riser down to it: the floor starts there
        if s.flat:
            if changed and s.length >= LEVEL_RUN_M:
                first("level", x0)
        elif _ramp_piece(s, RAMP_MIN_LENGTH_M) and abs(s.angle_deg) > FLIGHT_MIN_DEG:
            # steeper than any walkable ramp: a flight of stairs, its nosings in a line
            if surface is not None:
                first("rise" if s.angle_deg > 0 else "drop", x0)
            changed = True
        elif _ramp_piece(s, RAMP_MIN_LENGTH_M):
            if surface is not None and (surface.flat or surface.angle_deg * s.angle_deg < 0):
                # a ramp after other ground; the first surface seen is the ground walked
                first("ramp_up" if s.angle_deg > 0 else "ramp_down", x0)
            changed = True
        elif not _ramp_piece(s, 0.02):
            continue  # too short to be a surface of its own: noise, a nosing's corner
        surface = s
    return found


# The mode each kind of terrain shows: the geometry cue of fusion (GeometryFusion).
_SHOWN = {
    ("level", ""): "LG",
    ("stairs", "up"): "US",
    ("stairs", "down"): "DS",
    ("ramp", "up"): "UR",
    ("ramp", "down"): "DR",
}


def shown_mode(kind: str | None, direction: str | None = "") -> int:
    """The mode a frame's features show (`kind`, `direction` of TerrainFeatures or of a
    recorded /terrain/features message), as an index into MODES; -1 when unknown."""
    mode = _SHOWN.get((kind or "", "" if kind == "level" else direction or ""))
    return -1 if mode is None else MODES.index(mode)


def ground_ahead(slope_deg: float | None) -> int:
    """The mode the ground AHEAD_M ahead shows by its slope (`ahead_slope_deg` of
    TerrainFeatures or of a recorded /terrain/features message), as an index into MODES:
    a ramp up or down beyond FLAT_MAX_DEG, else level ground; -1 when not seen. The cue of
    fusion (SlopeFusion)."""
    if slope_deg is None or not math.isfinite(slope_deg):
        return -1
    if slope_deg > FLAT_MAX_DEG:
        return MODES.index("UR")
    if slope_deg < -FLAT_MAX_DEG:
        return MODES.index("DR")
    return MODES.index("LG")


def _slope_at(segments: list[_Segment], x_m: float) -> float | None:
    """The angle of the fitted segment over forward distance `x_m`, None where no segment
    covers it (a gap, an occlusion, the profile ends before)."""
    for s in segments:
        if min(s.start[0], s.end[0]) <= x_m <= max(s.start[0], s.end[0]):
            return float(s.angle_deg)
    return None


def _polyline_runs(bins: np.ndarray, rng: np.ndarray) -> list[np.ndarray]:
    """Median range per elevation-angle bin, near to far, cut at range jumps. `bins` and
    `rng` are sorted by bin, then by range.

    Each run is (K, 4): x, z, first bin, bin after the last (the vertex's own bin).
    """
    width = np.radians(ANGLE_BIN_DEG)
    starts = np.flatnonzero(np.concatenate(([True], bins[1:] != bins[:-1])))
    counts = np.diff(starts, append=len(bins))
    keep = counts >= MIN_BIN_POINTS
    starts, counts = starts[keep], counts[keep]
    median_rng = 0.5 * (rng[starts + (counts - 1) // 2] + rng[starts + counts // 2])
    own = bins[starts]
    centre = (own + 0.5) * width
    vertices = np.stack(
        [median_rng * np.cos(centre), median_rng * np.sin(centre), own, own + 1], axis=1
    )
    if len(vertices) < 2:
        return []
    step = np.hypot(*np.diff(vertices[:, :2], axis=0).T)
    cuts = np.flatnonzero(_jumps(step) | (np.diff(own) > 3)) + 1
    return [run for run in np.split(vertices, cuts) if len(run) >= 3]


def _jumps(step: np.ndarray) -> np.ndarray:
    """Steps between neighbouring vertices that break the polyline: longer than
    BREAK_GAP_M and JUMP_RATIO times the steps around them. Far level ground seen at a
    grazing angle has vertices BREAK_GAP_M apart by itself, and its range noise makes
    every other step long; a cut there would end each run on a near vertex (high) and
    start the next on a far one (low), and so tilt every far run up."""
    long = step > BREAK_GAP_M
    if not long.any():
        return long
    n = JUMP_WINDOW
    padded = np.pad(step, n, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * n + 1)
    around = np.median(np.delete(windows, n, axis=1), axis=1)
    return long & (step > JUMP_RATIO * around)


def _split(vertices: np.ndarray, lo: int, hi: int, out: list[tuple[int, int]]) -> None:
    """Douglas-Peucker: cut [lo, hi] where a vertex lies farther than the tolerance."""
    a, b = vertices[lo, :2], vertices[hi, :2]
    if hi - lo >= 2:
        d = b - a
        n = np.hypot(*d)
        rel = vertices[lo + 1 : hi, :2] - a
        dist = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) / max(n, 1e-9)
        k = int(np.argmax(dist))
        if dist[k] > SPLIT_TOL_M:
            _split(vertices, lo, lo + 1 + k, out)
            _split(vertices, lo + 1 + k, hi, out)
            return
    out.append((lo, hi))


def _fit_segments(run: np.ndarray, pts: np.ndarray, bins: np.ndarray) -> list[_Segment]:
    pieces: list[tuple[int, int]] = []
    _split(run, 0, len(run) - 1, pieces)
    fitted: list[tuple[int, int, _Segment]] = []  # (first vertex, last vertex, segment)
    for lo, hi in pieces:
        if hi - lo < 2:  # two vertices say nothing about a surface
            continue
        # A shared corner vertex belongs to both neighbours; their own points do not.
        first, stop = np.searchsorted(bins, (run[lo, 2], run[hi, 3]))
        seg = _fit_line(pts, int(first), int(stop))
        if seg is not None:
            fitted.append((lo, hi, seg))
    return [seg for _, _, seg in _merge(fitted, pts)]


def _merge(fitted: list[tuple[int, int, _Segment]], pts: np.ndarray):
    """The merge of split-and-merge: neighbours (sharing a corner vertex) one line explains
    about as well as two become one, the best pair first. The split's tolerance is a
    distance, and the range noise grows with distance: far level ground splits into short
    pieces whose angles scatter by degrees, each long enough to pass for a ramp."""
    cache: dict[tuple[int, int], _Segment | None] = {}
    while len(fitted) > 1:
        best, best_ratio = -1, MERGE_RSS_RATIO
        for i in range(len(fitted) - 1):
            (_, hi_a, a), (lo_b, _, b) = fitted[i], fitted[i + 1]
            if hi_a != lo_b:
                continue
            key = (a.first, b.stop)
            if key not in cache:
                cache[key] = _fit_line(pts, a.first, b.stop)
            m = cache[key]
            if m is None or m.count < MERGE_MIN_KEPT * (a.count + b.count):
                continue
            ratio = m.rss / max(a.rss + b.rss, 1e-12)
            if ratio <= best_ratio:
                best, best_ratio = i, ratio
        if best < 0:
            break
        (lo, _, _), (_, hi, _) = fitted[best], fitted[best + 1]
        merged = cache[(fitted[best][2].first, fitted[best + 1][2].stop)]
        fitted[best : best + 2] = [(lo, hi, merged)]
    return fitted


def _fit_line(pts: np.ndarray, first: int, stop: int) -> _Segment | None:
    """The line through pts[first:stop] by least squares along the camera's rays, refit
    once without the points beyond FIT_TRIM_M of it."""
    return _fit_points(pts, np.arange(first, stop), first, stop)


def _fit_points(pts: np.ndarray, index: np.ndarray, first: int = 0, stop: int = 0):
    """_fit_line on any set of the sorted profile's points (`index`: theirs in it)."""
    points = pts[index]
    for _ in range(2):
        if len(points) < 5:
            return None
        normal, offset = _ray_line(points)
        direction = np.array([-normal[1], normal[0]])
        dist = points @ normal - offset
        inside = np.abs(dist) <= FIT_TRIM_M
        if inside.all():
            break
        points, index = points[inside], index[inside]
    if not len(points):
        return None
    centre = points.sum(axis=0) / len(points)
    centre = centre - (centre @ normal - offset) * normal  # onto the line
    along = (points - centre) @ direction
    start, end = centre + along.min() * direction, centre + along.max() * direction
    # Travel direction from near to far: farther along the elevation angle.
    if np.arctan2(start[1], start[0]) > np.arctan2(end[1], end[0]):
        start, end = end, start
    d = end - start
    angle = float(np.degrees(np.arctan2(d[1], d[0])))
    return _Segment(
        profile=pts,
        index=index,
        start=start,
        end=end,
        angle_deg=angle,
        centre=centre,
        rms_m=float(np.sqrt((dist[inside] ** 2).sum() / np.count_nonzero(inside))),  # a mean
        first=first,
        stop=stop,
    )


def _ray_line(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit normal n and offset d of the line n . p = d through `points`, fitted where a
    time-of-flight camera errs: along each point's ray from the camera (the origin), by a
    share of the distance.

    A point at elevation angle a and range r lies on the line when 1 / r = A cos a +
    B sin a, with (A, B) = n / d: linear in (A, B), and the angle carries no noise. Least
    squares on 1 / r weighted by r^2 (its sigma is that of r / r^2, and the sensor's sigma
    of r grows with r) finds the line the rays measure. A perpendicular fit (total least
    squares) is biased here instead: on a stretch short against its noise the points
    spread along the rays, and the fit turns towards them (far level ground fits as
    sloping down). A line through the camera is no surface it sees; when the angles span
    too little to tell, the perpendicular fit stands in.
    """
    x, z = points[:, 0], points[:, 1]
    # The normal equations with u = (cos a, sin a) = p / r and weight r^2: sum r^2 u u^T
    # = sum p p^T and sum r^2 u / r = sum p, so (A, B) solves (sum p p^T) (A, B) = sum p.
    sxx, sxz, szz = float(x @ x), float(x @ z), float(z @ z)
    bx, bz = float(x.sum()), float(z.sum())
    det = sxx * szz - sxz * sxz
    if det > 1e-9 * (sxx + szz) ** 2:
        a = (szz * bx - sxz * bz) / det
        b = (sxx * bz - sxz * bx) / det
        norm = math.hypot(a, b)
        if norm > 0 and 1.0 / norm > 0.01:  # a line 1 cm or more from the camera
            return np.array([a, b]) / norm, 1.0 / norm
    centre = points.sum(axis=0) / len(points)  # = mean(axis=0), without its overhead
    _, normal = _principal_axes(points - centre)
    return normal, float(centre @ normal)


def _principal_axes(centred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction of largest spread and its normal: the SVD of a 2-D point set in
    closed form (a tenth of np.linalg.svd's cost, which adds up over many small fits)."""
    (sxx, sxy), (_, syy) = centred.T @ centred
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    c, s = math.cos(theta), math.sin(theta)
    return np.array([c, s]), np.array([-s, c])


def _stairs(segments: list[_Segment], hint: str | None) -> TerrainFeatures | None:
    flats = [i for i, s in enumerate(segments) if s.flat and s.length >= 0.02]
    # Steps between consecutive treads: (rise, index of the lower-x tread, of the other).
    up_rises: list[float] = []
    down_steps: list[tuple[float, int, int]] = []
    for i, j in zip(flats, flats[1:]):
        a, b = segments[i], segments[j]
        rise = b.level - a.level
        if not RISER_MIN_M <= abs(rise) <= RISER_MAX_M:
            continue
        gap = b.x_p2 - a.x_p98
        if rise > 0 and gap <= 0.05:
            up_rises.append(rise)
        elif rise < 0 and -0.02 <= gap <= MAX_HIDDEN_M:  # the lower tread is half hidden
            down_steps.append((-rise, i, j))
    # Going up, the risers face the camera: each is a stair edge.
    risers = [
        i
        for i, s in enumerate(segments)
        if s.angle_deg > 60 and 0.02 <= s.length <= RISER_MAX_M + 0.05
    ]
    up_evidence, down_evidence = len(up_rises) + len(risers), len(down_steps)
    if hint == "US" and up_evidence or not down_evidence:
        going_up = True
    elif hint == "DS" and down_evidence:
        going_up = False
    else:
        going_up = up_evidence > down_evidence
    if going_up:
        rises = up_rises or [r for r in (_complete_riser(segments, i) for i in risers) if r]
        if not rises and len(risers) < 2:
            return None
        edges = [segments[i].x_median for i in risers]
        tops = [float(segments[i].end[1]) for i in risers]
        bottoms = [float(segments[i].start[1]) for i in risers]
        depths = [
            e1 - e0
            for e0, e1, top, bottom in zip(edges, edges[1:], tops, bottoms[1:])
            if bottom >= top - 0.03
        ]  # the next riser starts where this one ends
        steps = max(len(rises), len(risers))
    else:
        rises = [r for r, _, _ in down_steps]
        # The nosing (far end of the upper tread) is the edge; chained steps share treads.
        nosing = {i: _nosing(segments[i], segments[j]) for _, i, j in down_steps}
        depths = [
            nosing[j] - nosing[i]
            for (_, i, j), (_, k, _) in zip(down_steps, down_steps[1:])
            if j == k
        ]
        steps = len(down_steps)
    depths = [d for d in depths if TREAD_MIN_M <= d <= TREAD_MAX_M]
    return TerrainFeatures(
        kind="stairs",
        riser_m=float(np.median(rises)) if rises else None,
        tread_m=float(np.median(depths)) if depths else None,
        direction="up" if going_up else "down",
        steps=steps,
    )


def _nosing(upper: _Segment, lower: _Segment) -> float:
    """Where a tread drops to the next one down.

    The last sample on the upper tread falls short of the edge; the ray grazing the edge
    lands on the lower tread at x_lower = x_edge * z_lower / z_upper (camera at the
    origin), and the first sample there lies beyond. The mean of both cancels most of
    the sampling bias.
    """
    last, first = upper.x_p98, lower.x_p2
    if upper.level < -0.02 and lower.level < upper.level:
        return 0.5 * (last + first * upper.level / lower.level)
    return last


def _complete_riser(segments: list[_Segment], i: int) -> float | None:
    """A riser's height when both its foot (a tread) and its top (what follows) are seen."""
    riser = segments[i]
    below = [s for s in segments[:i] if s.flat]
    if not below or i + 1 >= len(segments):
        return None
    tread = below[-1]
    foot_ok = abs(tread.level - riser.start[1]) < 0.02 and abs(tread.end[0] - riser.start[0]) < 0.05
    top_ok = abs(segments[i + 1].start[1] - riser.end[1]) < 0.02
    rise = float(riser.end[1]) - tread.level
    return rise if foot_ok and top_ok and RISER_MIN_M <= rise <= RISER_MAX_M else None


def _ramp(segments: list[_Segment], hint: str | None) -> TerrainFeatures | None:
    min_length = 0.15 if hint in ("UR", "DR") else RAMP_MIN_LENGTH_M
    slanted = [s for s in segments if _ramp_piece(s, min_length)]
    if not slanted:
        return None
    ramp = max(slanted, key=lambda s: s.length)
    return TerrainFeatures(
        kind="ramp", slope_deg=ramp.angle_deg, direction="up" if ramp.angle_deg > 0 else "down"
    )


def _ramp_piece(s: _Segment, min_length: float) -> bool:
    return not s.flat and abs(s.angle_deg) <= RAMP_MAX_DEG and s.length >= min_length


def _flat_at(segments: list[_Segment], x_m: float) -> bool:
    """Whether the fitted segment over forward distance `x_m` is flat (False where none)."""
    for s in segments:
        if min(s.start[0], s.end[0]) <= x_m <= max(s.start[0], s.end[0]):
            return s.flat
    return False


def _level_shown(segments: list[_Segment], x_near: float) -> bool:
    """Whether the image shows level ground: the ground AHEAD_M ahead is flat, or flat
    pieces cover more of the image's forward reach (IMAGE_REACH_M from the nearest point,
    `x_near`) than the ramp would: the image's terrain is the one that fills most of it
    (a ramp that starts inside it, or a far zig-zag of noise, is not yet what it shows)."""
    if _flat_at(segments, AHEAD_M):
        return True
    lo, hi = x_near, x_near + IMAGE_REACH_M

    def cover(s: _Segment) -> float:
        a, b = sorted((float(s.start[0]), float(s.end[0])))
        return max(0.0, min(b, hi) - max(a, lo))

    ramps = [cover(s) for s in segments if _ramp_piece(s, RAMP_MIN_LENGTH_M)]
    return not ramps or sum(cover(s) for s in segments if s.flat) >= max(ramps)


def _level(fit: ProfileFit, shown: bool = False) -> TerrainFeatures | None:
    """Level ground: flat pieces most of what is seen, or (`shown`, _level_shown) level
    ground what the image shows."""
    segments = fit.segments
    total = sum(s.length for s in segments)
    flat = [s for s in segments if s.flat]
    if not flat or (not shown and sum(s.length for s in flat) < 0.5 * total):
        return None
    # One tilt from all the stretches of level ground (a curb splits level ground into
    # stretches at two heights, not two tilts): their angles weighted by the inverse square
    # of their standard errors, so that a short far stretch the noise tilts counts for little.
    stretches = fit.stretches
    weights = np.array([1.0 / max(s.angle_se_deg, MIN_ANGLE_SE_DEG) ** 2 for s in stretches])
    angles = np.array([s.angle_deg for s in stretches])
    # A tilt the noise leaves this uncertain cannot tell level ground from a walkway's
    # 1:20 (far ground alone, at a grazing angle): level, its slope not measured.
    slope = float(weights @ angles / weights.sum())
    measured = 1.0 / math.sqrt(float(weights.sum())) <= LEVEL_SLOPE_MAX_SE_DEG
    return TerrainFeatures(kind="level", slope_deg=slope if measured else None)


def _level_stretches(segments: list[_Segment], refit=None) -> list[_Segment]:
    """The stretches of level ground, each one line along the rays through the points of
    its flat pieces and the short pieces between them that rise less than a riser.

    Far level ground splits into pieces by the range noise, correlated over a few pixels:
    a patch read too far lies low and far along its rays, the next one read too near lies
    high and near, so the polyline zig-zags in long shallow pieces down and short steep
    ones up. Only the long ones pass as flat; their angles alone tilt the ground down.
    One line through the whole stretch sees the noise along the rays, as it is.

    refit: what fits a line through points of the sorted profile, _fit_points' way (its
    arguments: the profile and the points' indices; None: _fit_points)."""
    stretches: list[list[_Segment]] = []
    current: list[_Segment] = []
    for s in segments:
        rise = abs(float(s.end[1] - s.start[1]))
        ground = s.flat or (s.length < RAMP_MIN_LENGTH_M and rise < RISER_MIN_M)
        joins = bool(current) and abs(float(s.start[1] - current[-1].end[1])) < RISER_MIN_M
        if ground and (joins or not current):
            current.append(s)
            continue
        if current:
            stretches.append(current)
        current = [s] if ground else []
    if current:
        stretches.append(current)
    out = []
    for stretch in stretches:
        flat = [s for s in stretch if s.flat]
        if not flat:
            continue
        if len(stretch) == 1:
            out.append(stretch[0])
            continue
        # neighbours share their corner's points: each point once
        index = np.unique(np.concatenate([s.index for s in stretch]))
        fitted = (refit or _fit_points)(stretch[0].profile, index)
        out.extend([fitted] if fitted is not None and fitted.flat else flat)
    return out
