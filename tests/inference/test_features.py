import numpy as np
import pytest

from inference.config import PreprocessConfig
from inference.features import TerrainFeatures, terrain_features
from inference.preprocess import preprocess
from tests import terrain_raycast as tr

PARAMS = PreprocessConfig()


def poses(count: int, seed: int, pitch_deg: tuple[float, float]):
    """Thigh orientations (pitch: negative = thigh raised, camera looking higher) and
    camera heights of a walking subject, any heading."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        q = tr.thigh_quaternion(rng.uniform(*pitch_deg), rng.uniform(-3, 3), rng.uniform(-180, 180))
        yield q, rng.uniform(0.5, 0.6), k


def features_over_poses(
    terrain, count: int = 8, seed: int = 0, hint=None, pitch_deg: tuple[float, float] = (-20, 10)
):
    """Features of the terrain seen from a set of poses, with the range noise of the
    authors' simulation (+-1 cm); frames the preprocessing flags are left out."""
    out = []
    for q, height, k in poses(count, seed, pitch_deg):
        xyz, conf = tr.render(terrain, q, height_m=height, noise_m=0.01, seed=seed * 100 + k)
        pre = preprocess(xyz, conf, q, PARAMS)
        if pre.ok:
            out.append(terrain_features(pre.profile, hint))
    return out


@pytest.mark.parametrize("angle", [-20.0, -15.0, -10.0, 10.0, 15.0, 20.0])
def test_ramp_slope_within_a_degree(angle):
    feats = features_over_poses(tr.ramp(angle), seed=int(angle) + 30)
    ramps = [f for f in feats if f.kind == "ramp"]
    assert len(ramps) >= 0.8 * len(feats) >= 5
    assert abs(np.median([f.slope_deg for f in ramps]) - angle) < 1.0
    assert all(f.direction == ("up" if angle > 0 else "down") for f in ramps)
    assert all(f.riser_m is None and f.tread_m is None for f in ramps)


def test_ramp_ahead_of_level_ground():
    feats = features_over_poses(tr.ramp(14.0, start_m=0.5), seed=3)
    ramps = [f for f in feats if f.kind == "ramp"]
    assert len(ramps) >= 0.7 * len(feats)
    assert abs(np.median([f.slope_deg for f in ramps]) - 14.0) < 1.0


def test_level_ground():
    feats = features_over_poses(tr.level(), seed=5)
    assert len(feats) >= 5 and all(f.kind == "level" for f in feats)
    assert all(abs(f.slope_deg) < 1.0 for f in feats)
    assert all(f.riser_m is None and f.tread_m is None for f in feats)
    assert all(f.inlier_fraction > 0.95 and f.residual_m < 0.01 for f in feats)


# The authors' stairs: riser 0.15 +- 0.05 m, tread 0.33 +- 0.05 m, first riser 0.2 m ahead.
STAIRS = [(0.11, 0.29), (0.15, 0.33), (0.19, 0.37)]


@pytest.mark.parametrize("up", [True, False], ids=["up", "down"])
@pytest.mark.parametrize("riser, tread", STAIRS)
def test_stairs_riser_and_tread_within_a_centimetre(riser, tread, up):
    # Going down, the thigh is raised less: the camera looks further down.
    feats = features_over_poses(
        tr.stairs(riser, tread, first_m=0.2, up=up),
        count=10,
        seed=int(riser * 100) + up,
        pitch_deg=(-20, 10) if up else (-10, 15),
    )
    stairs = [f for f in feats if f.kind == "stairs"]
    assert len(stairs) >= 0.7 * len(feats) >= 5
    assert all(f.direction == ("up" if up else "down") for f in stairs)
    risers = [f.riser_m for f in stairs if f.riser_m is not None]
    treads = [f.tread_m for f in stairs if f.tread_m is not None]
    assert len(risers) >= 0.7 * len(stairs)
    assert len(treads) >= 0.4 * len(stairs)  # needs two stair edges in view
    assert abs(np.median(risers) - riser) < 0.01
    assert abs(np.median(treads) - tread) < 0.01
    assert all(f.slope_deg is None for f in stairs)


def sagittal(polyline, spacing=0.003, noise=0.0, seed=0):
    """Points along a polyline (x, z), as a densely sampled profile."""
    rng = np.random.default_rng(seed)
    out = []
    for (x0, z0), (x1, z1) in zip(polyline[:-1], polyline[1:]):
        n = max(int(np.hypot(x1 - x0, z1 - z0) / spacing), 2)
        t = np.linspace(0, 1, n, endpoint=False)
        out.append(np.stack([x0 + t * (x1 - x0), z0 + t * (z1 - z0)], axis=1))
    pts = np.concatenate(out)
    return (pts + rng.uniform(-noise, noise, pts.shape)).astype(np.float32)


def test_the_fused_decision_only_relaxes_the_evidence():
    # Level ground with a short incline (20 cm long, 14 degrees) in the middle.
    k = np.tan(np.radians(14))
    profile = sagittal([(0.3, -0.55), (0.7, -0.55), (0.9, -0.55 + 0.2 * k), (1.4, -0.55 + 0.2 * k)])
    assert terrain_features(profile).kind == "level"
    hinted = terrain_features(profile, "UR")
    assert hinted.kind == "ramp" and hinted.slope_deg == pytest.approx(14.0, abs=1.0)
    # A hint never invents terrain that is not there.
    flat = sagittal([(0.3, -0.55), (1.4, -0.55)], noise=0.005)
    for hint in ("US", "DS", "UR", "DR", "LG", None):
        assert terrain_features(flat, hint).kind == "level"


def test_stairs_from_a_clean_profile():
    # Up stairs as the camera sees them: treads and risers, nothing hidden.
    profile = sagittal(
        [
            (0.3, -0.55),
            (0.5, -0.55),
            (0.5, -0.39),
            (0.8, -0.39),
            (0.8, -0.23),
            (1.1, -0.23),
            (1.1, -0.07),
        ]
    )
    f = terrain_features(profile)
    assert f.kind == "stairs" and f.direction == "up"
    assert f.riser_m == pytest.approx(0.16, abs=0.003)
    assert f.tread_m == pytest.approx(0.30, abs=0.003)
    assert f.steps == 3
    assert len(f.segments) >= 6


@pytest.mark.parametrize(
    "profile",
    [
        np.zeros((0, 2)),
        np.full((50, 2), np.nan),
        np.ones((3, 2)),
        np.zeros((100, 2)),
        np.random.default_rng(0).normal(size=(500, 2)),
    ],
)
def test_degenerate_profiles_are_unknown(profile):
    f = terrain_features(profile)
    assert isinstance(f, TerrainFeatures) and f.kind == "unknown"
    assert f.slope_deg is None and f.riser_m is None and f.tread_m is None


def test_the_ground_ahead_is_the_slope_a_step_ahead_not_the_terrain_in_view():
    """On a ramp, the ground a step ahead slopes as the ramp; on level ground with a ramp up
    farther ahead the features show the ramp, the ground ahead stays level (the cue of
    steady+slope: a landing shows the next ramp only beyond it)."""
    from inference.features import AHEAD_M, ground_ahead

    on_ramp = features_over_poses(tr.ramp(-12.0), seed=7)
    ahead = [ground_ahead(f.ahead_slope_deg) for f in on_ramp]
    assert ahead.count(4) >= 0.8 * len(on_ramp) >= 5  # DR
    assert all(abs(f.ahead_slope_deg + 12.0) < 1.0 for f in on_ramp if f.ahead_slope_deg)
    before_ramp = features_over_poses(tr.ramp(12.0, start_m=AHEAD_M + 0.8), seed=8)
    assert sum(f.kind == "ramp" and f.direction == "up" for f in before_ramp) >= 4
    assert [ground_ahead(f.ahead_slope_deg) for f in before_ramp] == [0] * len(before_ramp)


def test_a_level_decision_keeps_level_ground_while_the_ground_a_step_ahead_is_flat():
    """Level ground with a ramp up beyond the image's reach: unhinted (or with a ramp
    decision) the features show the ramp; a fused decision of level ground keeps the frame
    level, its slope that of the level ground, while the ground a step ahead is flat."""
    from inference.features import AHEAD_M

    terrain = tr.ramp(12.0, start_m=AHEAD_M + 0.8)
    plain = features_over_poses(terrain, seed=8)
    assert sum(f.kind == "ramp" for f in plain) >= 4
    assert sum(f.kind == "ramp" for f in features_over_poses(terrain, seed=8, hint="UR")) >= 4
    level = features_over_poses(terrain, seed=8, hint="LG")
    assert len(level) >= 5 and all(f.kind == "level" for f in level)
    assert all(abs(f.slope_deg) < 1.0 for f in level)
    # On the ramp itself the decision does not hide it.
    on_ramp = features_over_poses(tr.ramp(12.0), seed=9, hint="LG")
    assert sum(f.kind == "ramp" for f in on_ramp) >= 0.8 * len(on_ramp) >= 5


@pytest.mark.parametrize(
    "slope, mode",
    [(None, -1), (float("nan"), -1), (0.0, 0), (2.9, 0), (-2.9, 0), (3.5, 3), (-3.5, 4)],
)
def test_ground_ahead_names_the_mode_its_slope_shows(slope, mode):
    from inference.features import ground_ahead

    assert ground_ahead(slope) == mode


def ray_profile(height_m: float, noise_rel: float, rng: np.random.Generator) -> np.ndarray:
    """Level ground `height_m` below the camera as a ToF camera on the thigh measures it in
    the corridor: pixel rows 0.26 deg apart, as many points a row as a 10 cm corridor holds
    at that range, range noise `noise_rel` times the range along each ray."""
    rows = []
    for elevation in np.radians(np.arange(-80.0, -12.0, 0.26)):
        r = height_m / -np.sin(elevation)
        if r * np.cos(elevation) > 2.45:
            continue
        n = max(2, int(0.1 / (r * np.radians(62.0 / 224))))
        measured = r * (1 + noise_rel * rng.standard_normal(n))
        rows.append(np.stack([measured * np.cos(elevation), measured * np.sin(elevation)], 1))
    return np.concatenate(rows).astype(np.float32)


@pytest.mark.parametrize("noise_rel", [0.0142, 0.0227], ids=["indoor", "outdoor"])
def test_level_ground_stays_level_under_range_noise_along_the_rays(noise_rel):
    """The pico flexx's noise runs along each ray and grows with the range (1.42 % of the
    distance at 15 fps, 1.6 times that in sunlight: devices.simulator.render). A fit that
    minimises perpendicular distances turns short far stretches towards the rays (down);
    cutting the polyline at every long far step tilts far runs up. Level stays level."""
    rng = np.random.default_rng(48)
    slopes = []
    for _ in range(80):
        f = terrain_features(ray_profile(rng.uniform(0.5, 0.6), noise_rel, rng), "LG")
        slopes.append(f.slope_deg if f.slope_deg is not None else np.nan)
    slopes = np.array(slopes)
    assert np.isfinite(slopes).mean() >= 0.95
    slopes = slopes[np.isfinite(slopes)]
    assert abs(np.median(slopes)) < 0.5
    assert np.mean(np.abs(slopes) > 3.0) <= 0.05


def test_a_level_decision_keeps_level_ground_while_it_fills_most_of_the_image():
    """A ramp up beginning inside the image (the ground a step ahead is the ramp): under a
    fused decision of level ground the frame is level, its slope level ground's, while
    level ground fills most of the image's columns (the rule that names the image's
    terrain), a ramp once the ramp does; unhinted the features show the ramp."""
    start = 0.85
    terrain = tr.ramp(10.0, start_m=start)
    levels, ramps = 0, 0
    for q, height, k in poses(24, 5, (-20, 10)):
        xyz, conf = tr.render(terrain, q, height_m=height, noise_m=0.01, seed=500 + k)
        pre = preprocess(xyz, conf, q, PARAMS)
        if not pre.ok:
            continue
        columns = np.flatnonzero(pre.image.any(axis=0))
        level_share = np.mean(pre.origin_m[0] + (columns + 0.5) * PARAMS.cell_m < start)
        hinted = terrain_features(pre.profile, "LG")
        assert terrain_features(pre.profile).kind == "ramp"
        if level_share > 0.52:
            assert hinted.kind == "level" and abs(hinted.slope_deg) < 1.0, level_share
            levels += 1
        elif level_share <= 0.4:
            assert hinted.kind == "ramp" and hinted.slope_deg == pytest.approx(10.0, abs=1.0)
            ramps += 1
    assert levels >= 3 and ramps >= 3


def far_ray_profile(height_m: float, noise_rel: float, rng: np.random.Generator) -> np.ndarray:
    """ray_profile seen from a thigh swung forward, the nearest ground 1.3 m ahead, its
    range noise correlated over 3 pixel rows (as royale's adaptive filter leaves it)."""
    elevations = np.radians(np.arange(-22.0, -12.0, 0.26))
    common = np.convolve(rng.standard_normal(len(elevations) + 2), np.ones(3) / 3**0.5, "valid")
    rows = []
    for elevation, offset in zip(elevations, common):
        r = height_m / -np.sin(elevation)
        if r * np.cos(elevation) > 2.45:
            continue
        n = max(2, int(0.1 / (r * np.radians(62.0 / 224))))
        measured = r * (1 + noise_rel * (offset + 0.3 * rng.standard_normal(n)))
        rows.append(np.stack([measured * np.cos(elevation), measured * np.sin(elevation)], 1))
    return np.concatenate(rows).astype(np.float32)


@pytest.mark.parametrize(
    "noise_rel, most_beyond", [(0.0142, 0.10), (0.0227, 0.20)], ids=["indoor", "outdoor"]
)
def test_far_level_ground_zig_zagging_with_the_noise_stays_level(noise_rel, most_beyond):
    """Far level ground alone: patches of correlated noise read too far lie low and far
    along their rays, the next ones high and near, so the polyline zig-zags in long shallow
    pieces down and short steep ones up. Only the long ones pass as flat: their angles
    alone tilt level ground down (outdoors by 2 deg at the median)."""
    rng = np.random.default_rng(7)
    slopes = []
    for _ in range(60):
        f = terrain_features(far_ray_profile(rng.uniform(0.5, 0.6), noise_rel, rng), "LG")
        if f.slope_deg is not None:
            slopes.append(f.slope_deg)
    assert len(slopes) >= 40
    assert abs(np.median(slopes)) < 0.5
    assert np.mean(np.abs(slopes) > 3.0) <= most_beyond


# ---- edges: where the terrain ahead changes ------------------------------------------------


def edges_over_poses(terrain, kind: str, seed: int, count: int = 10) -> list[float | None]:
    """edge_<kind>_m of the terrain seen from a set of walking poses."""
    feats = features_over_poses(terrain, count=count, seed=seed, pitch_deg=(-15, 5))
    return [getattr(f, f"edge_{kind}_m") for f in feats]


def crest(angle_deg: float, at_m: float) -> list[tuple[float, float]]:
    """A ramp under the camera that ends `at_m` ahead in level ground (a crest, going up;
    the foot of a ramp down)."""
    k = np.tan(np.radians(angle_deg))
    return [(-5.0, -(at_m + 5.0) * k), (at_m, 0.0), (10.0, 0.0)]


@pytest.mark.parametrize(
    ("terrain", "kind", "at_m"),
    [
        (tr.stairs(0.16, 0.3, first_m=1.2), "rise", 1.2),
        (tr.stairs(0.17, 0.32, first_m=1.0, up=False), "drop", 1.0),
        (tr.ramp(10.0, start_m=1.1), "ramp_up", 1.1),
        (tr.ramp(-9.0, start_m=1.1), "ramp_down", 1.1),
        (crest(8.0, 1.1), "level", 1.1),
        (crest(-10.0, 1.0), "level", 1.0),
    ],
)
def test_the_first_edge_ahead_is_where_the_terrain_changes(terrain, kind, at_m):
    seen = [x for x in edges_over_poses(terrain, kind, seed=int(at_m * 100)) if x is not None]
    assert len(seen) >= 6
    assert abs(np.median(seen) - at_m) < 0.04


@pytest.mark.parametrize("kind", ["rise", "drop", "ramp_up", "ramp_down", "level"])
def test_level_ground_has_no_edge(kind):
    assert all(x is None for x in edges_over_poses(tr.level(), kind, seed=7))


def test_a_ramp_underfoot_is_no_ramp_edge():
    """The ground walked is no edge: on a ramp, the ramp's start is behind."""
    assert all(x is None for x in edges_over_poses(tr.ramp(10.0), "ramp_up", seed=8))
