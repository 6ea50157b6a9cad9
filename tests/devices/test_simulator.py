"""The terrain-walk simulator: courses, walker, rendering, ground truth, error images."""

import numpy as np
import pytest

from devices.frames import MODES, DepthFrame
from devices.rotations import mounting_matrix, quat_to_matrix
from devices.simulator import (
    PAPER_TRIAL,
    ErrorEvent,
    Simulator,
    Walk,
    make_course,
)


@pytest.fixture(scope="module")
def indoor():
    return Simulator(make_course("indoor", 0), seed=0)


@pytest.fixture(scope="module")
def outdoor():
    return Simulator(make_course("outdoor", 3), seed=3)


def leveled(frame: DepthFrame, tilt_deg: float = 35.0) -> np.ndarray:
    """Valid points rotated as the capture pipeline does: thigh quaternion and mounting."""
    rotation = quat_to_matrix(np.array(frame.truth["thigh_quaternion"])) @ mounting_matrix(
        0, tilt_deg, 0
    )
    return frame.xyz[frame.confidence > 0] @ rotation.T


def clean_times(sim: Simulator, mode: str, fps: float = 5.0):
    """Frame times whose truth is `mode`, no error image."""
    for k in range(int(sim.duration_s * fps)):
        t = k / fps
        if sim.walk.event_at(t) is None:
            segment, _ = sim.truth_at(t)
            if sim.course.segments[segment].mode == mode:
                yield t


# ---- courses -------------------------------------------------------------------------------


def test_default_course_is_one_trial_of_the_paper():
    course = make_course()
    assert course.modes == PAPER_TRIAL
    assert sum(m == "LG" for m in course.modes) == 3
    assert sorted(m for m in course.modes if m != "LG") == ["DR", "DS", "UR", "US"]
    for a, b in zip(course.segments, course.segments[1:]):  # contiguous, no jumps
        assert b.x0 == pytest.approx(a.x1) and b.z0 == pytest.approx(a.z1)
    assert course.length_m == pytest.approx(sum(s.length_m for s in course.segments))


@pytest.mark.parametrize("preset", ["indoor", "outdoor"])
def test_presets_randomise_within_the_issue_ranges(preset):
    courses = [make_course(preset, seed) for seed in range(40)]
    segs = [s for c in courses for s in c.segments]
    stairs = [s for s in segs if s.mode in ("US", "DS")]
    ramps = [s for s in segs if s.mode in ("UR", "DR")]
    assert all(0.10 <= s.riser_m <= 0.20 and 0.25 <= s.tread_m <= 0.38 for s in stairs)
    assert all(5 <= s.slope_deg <= 15 for s in ramps)
    assert np.ptp([s.riser_m for s in stairs]) > 0.05  # really randomised
    assert len({round(c.length_m, 6) for c in courses}) == len(courses)
    curbs = sum(len(s.curbs) for s in segs)
    if preset == "outdoor":
        assert curbs > 0 and all(c.bump_m > 0 and len(c.boxes) > 10 for c in courses)
    else:
        assert curbs == 0 and all(c.bump_m == 0 for c in courses)


def test_same_seed_same_course_and_seeds_differ():
    assert make_course("outdoor", 5) == make_course("outdoor", 5)
    assert make_course("outdoor", 5) != make_course("outdoor", 6)


def test_turning_from_up_to_down_inserts_a_level_landing():
    course = make_course("indoor", 1, modes=["LG", "US", "DS", "UR", "LG"])
    assert course.modes == ("LG", "US", "LG", "DS", "LG", "UR", "LG")
    landing = course.segments[2]
    assert 1.525 <= landing.length_m <= 2.0  # ADA 2010 405.7.3: 60 in at least


def test_stair_heights_step_by_one_riser_per_tread():
    seg = next(s for s in make_course("indoor", 2).segments if s.mode == "US")
    x = seg.x0 + (np.arange(seg.steps) + 0.5) * seg.tread_m
    np.testing.assert_allclose(np.diff(seg.height_at(x)), seg.riser_m)
    assert seg.z1 == pytest.approx(seg.z0 + seg.steps * seg.riser_m)


def test_unknown_names_are_errors():
    with pytest.raises(ValueError, match="known: indoor, outdoor"):
        make_course("beach")
    with pytest.raises(ValueError, match="unknown mode"):
        make_course("indoor", modes=["LG", "XX"])


# ---- walker --------------------------------------------------------------------------------


def test_walker_swings_the_thigh_and_climbs_with_the_terrain():
    course = make_course("indoor", 0)
    walk = Walk(course, seed=0)
    t = np.linspace(0, walk.duration_s, 2000)
    flexion = np.degrees(walk.flexion(t))
    assert 40 < np.ptp(flexion) < 85  # +-19 degrees on level ground, more on stairs and lifts
    # Level ground, no high knee lifts: 38 degrees (normal walking's thigh motion), times the
    # walker's own scale (0.9-1.1).
    calm = Walk(course, seed=0, events=[])
    level = t[calm.position(t) < course.segments[0].x1 - 1.0]
    assert 37 <= np.ptp(np.degrees(calm.flexion(level))) / calm.amp_scale <= 39
    hip = np.array([walk.hip_position(ti) for ti in t[::20]])
    ground = course.height_at(hip[:, 0])
    np.testing.assert_allclose(hip[:, 2] - ground, 0.9, atol=0.12)
    assert np.all(np.diff(walk.position(t)) >= 0)


def test_thigh_quaternion_accepts_arrays():
    walk = Walk(make_course("indoor", 0))
    t = np.array([0.5, 3.0, 7.25])
    np.testing.assert_allclose(
        walk.thigh_quaternion(t), np.stack([walk.thigh_quaternion(ti) for ti in t])
    )


def test_error_image_rates_per_preset():
    """Error images on about a seventh of the frames, more outdoors; objects that look like
    a terrain on a few per cent, fewer outdoors (docs/simulator.md, "Classifier errors")."""

    def share(preset):
        frames, kinds = 0, {}
        for seed in range(12):
            walk = Walk(make_course(preset, seed), seed=seed)
            t = np.arange(0, walk.duration_s, 1 / 15)
            frames += len(t)
            for ti in t:
                event = walk.event_at(ti)
                if event is not None:
                    kinds[event.kind] = kinds.get(event.kind, 0) + 1
        return sum(kinds.values()) / frames, {k: n / frames for k, n in kinds.items()}

    (indoor, inside), (outdoor, outside) = share("indoor"), share("outdoor")
    assert 0.10 < indoor < 0.17 and indoor < outdoor < 0.20
    assert set(inside) == set(outside) == {"swing_blur", "sky", "foot", "occlusion", "object"}
    assert 0.025 < inside["object"] < 0.06 and outside["object"] < inside["object"]


# ---- rendering -----------------------------------------------------------------------------


def test_frames_look_like_royale_frames(indoor, outdoor):
    for sim, t in ((indoor, 2.0), (outdoor, 6.0), (indoor, 12.0)):
        f = sim.render(t, index=7)
        assert f.index == 7 and f.device_time_ns == int(t * 1e9)
        assert f.xyz.shape == (171, 224, 3) and f.xyz.dtype == np.float32
        assert f.confidence.shape == (171, 224) and f.confidence.dtype == np.uint8
        assert f.gray.dtype == np.uint16
        invalid = f.confidence == 0
        assert np.all(f.xyz[invalid] == 0)
        z = f.xyz[~invalid][:, 2]
        assert np.all(z > 0.05) and np.all(np.linalg.norm(f.xyz[~invalid], axis=1) < 4.3)
        assert set(f.truth) >= {"mode", "camera_pose", "thigh_quaternion", "segment", "error"}
        assert f.truth["mode"] in MODES


def test_outdoor_has_more_invalid_and_noisier_pixels(indoor, outdoor):
    valid_in = np.mean([(indoor.render(t).confidence > 0).mean() for t in (1, 2)])
    valid_out = np.mean([(outdoor.render(t).confidence > 0).mean() for t in (1, 2)])
    assert valid_out < valid_in


def test_rendering_is_deterministic_for_a_seed(indoor):
    a, b = indoor.render(4.2), indoor.render(4.2)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    again = Simulator(make_course("indoor", 0), seed=0).render(4.2)
    np.testing.assert_array_equal(a.xyz, again.xyz)
    assert a.truth == again.truth
    other = Simulator(make_course("indoor", 0), seed=1).render(4.2)
    assert not np.array_equal(a.xyz, other.xyz)


def test_camera_pose_is_the_thigh_composed_with_the_mounting(indoor):
    f = indoor.render(3.3)
    pose = np.array(f.truth["camera_pose"])
    q = indoor.thigh_quaternion(3.3)
    np.testing.assert_allclose(f.truth["thigh_quaternion"], q)
    np.testing.assert_allclose(
        pose[:3, :3], quat_to_matrix(q) @ mounting_matrix(0, 35, 0), atol=1e-12
    )


def test_leveled_level_ground_lies_one_camera_height_below(indoor):
    """What the capture pipeline does with the configured mounting must level the cloud."""
    checked = 0
    for t in list(clean_times(indoor, "LG"))[::5]:
        f = indoor.render(t)
        pose = np.array(f.truth["camera_pose"])
        under = indoor.course.segment_index(pose[0, 3])
        if f.truth["view_share"] < 1.0 or under != f.truth["segment"]:
            continue  # the walker stands on the same level ground that it looks at
        height = pose[2, 3] - indoor.course.segments[under].z0
        p = leveled(f)
        floor = p[(np.abs(p[:, 1]) < 0.3) & (p[:, 0] < 1.5)]
        assert len(floor) > 500
        assert np.median(floor[:, 2]) == pytest.approx(-height, abs=0.015)
        assert np.std(floor[:, 2]) < 0.03  # flat: 1 % noise, no tilt left
        checked += 1
    assert checked >= 5


def test_ramps_keep_their_slope_after_leveling(indoor):
    for mode, sign in (("UR", 1), ("DR", -1)):
        seg = next(s for s in indoor.course.segments if s.mode == mode)
        slopes = []
        for t in list(clean_times(indoor, mode))[::4]:
            f = indoor.render(t)
            if f.truth["view_share"] < 0.9:
                continue
            p = leveled(f)
            near = p[(np.abs(p[:, 1]) < 0.1) & (p[:, 0] < 1.2)]
            if len(near) > 300:
                slopes.append(np.degrees(np.arctan(np.polyfit(near[:, 0], near[:, 2], 1)[0])))
        assert len(slopes) >= 3
        assert np.median(slopes) == pytest.approx(sign * seg.slope_deg, abs=2.0)


def test_stairs_show_treads_one_riser_apart(indoor):
    seg = next(s for s in indoor.course.segments if s.mode == "US")
    t = next(t for t in clean_times(indoor, "US") if indoor.render(t).truth["view_share"] == 1)
    f = indoor.render(t)
    p = leveled(f)
    z = p[(np.abs(p[:, 1]) < 0.1) & (p[:, 0] < 1.5), 2]
    hist, edges = np.histogram(z, bins=np.arange(z.min() - 0.01, z.max() + 0.02, 0.01))
    peaks = edges[:-1][hist > 0.05 * len(z)]
    treads = [peaks[0]] + [p for a, p in zip(peaks, peaks[1:]) if p - a > 0.05]
    assert len(treads) >= 2
    assert np.diff(treads)[0] == pytest.approx(seg.riser_m, abs=0.02)


# ---- ground truth --------------------------------------------------------------------------


def _image(frame, tilt_deg: float = 35.0):
    from devices.config import MountingConfig
    from inference.config import PreprocessConfig
    from inference.preprocess import preprocess_frame

    q = np.array(frame.truth["thigh_quaternion"])
    return preprocess_frame(
        frame, q, PreprocessConfig(), mounting=MountingConfig(pitch_deg=tilt_deg)
    )


def test_truth_is_what_the_classifiers_image_shows(indoor):
    """The truth's segment lies in the stretch of course the classifier's image holds, and
    fills over half of the image's terrain columns."""
    checked = 0
    for k in range(0, int(indoor.duration_s * 15), 7):
        f = indoor.render(k / 15)
        if f.truth["error"]:
            continue
        pre = _image(f)
        if not pre.ok or f.truth["view_share"] == 0.0:
            continue
        checked += 1
        assert f.truth["view_share"] >= 0.5 - 1e-9
        pose = np.array(f.truth["camera_pose"])
        x0 = pose[0, 3] + pre.origin_m[0]  # the image's first column on the course
        segment = indoor.course.segments[f.truth["segment"]]
        assert segment.mode == f.truth["mode"]
        assert segment.x0 < x0 + 1.05 and segment.x1 > x0 - 0.05
    assert checked > 30


def test_a_staircase_in_the_image_is_stairs_while_the_walker_is_still_on_the_floor(indoor):
    """Approaching the up stairs, the truth turns US when the image mostly shows them,
    before the walker's own mode does; the walker's mode turns later."""
    seg = next(i for i, s in enumerate(indoor.course.segments) if s.mode == "US")
    times = np.arange(0, indoor.duration_s, 1 / 15)
    truth = [indoor.course.segments[indoor.truth_at(t)[0]].mode for t in times[::2]]
    walker = [indoor.locomotion_mode(t) for t in times[::2]]
    first_image = truth.index("US")
    first_walker = walker.index("US")
    assert first_image < first_walker  # the camera looks ahead
    f = indoor.render(times[::2][first_image])
    assert f.truth["mode"] == "US" and f.truth["locomotion_mode"] == "LG"
    assert f.truth["segment"] == seg
    image = _image(f).image
    assert (image.sum(axis=0) >= 10).sum() >= 1  # a riser in the image


def test_a_view_of_no_terrain_falls_back_to_the_terrain_ahead():
    walk = Walk(make_course("indoor", 0))
    ts = np.linspace(1.5, 3.0, 300)
    t = float(ts[np.argmax(walk.flexion(ts))])
    course = make_course("indoor", 0)
    sky = Simulator(course, seed=0, events=[ErrorEvent("sky", t - 0.15, t + 0.15, 1.0, 11)])
    segment, share = sky.truth_at(t)
    assert share == 0.0 and segment == sky.lookahead_segment(t)
    plain = Simulator(course, seed=0, events=[])
    # a foot or an occlusion does not change the terrain: the truth is cast without them
    foot = Simulator(course, seed=0, events=[ErrorEvent("foot", 1.0, 3.0, 1.0, 11)])
    a, b = foot.render(2.0).truth, plain.render(2.0).truth
    assert (a["mode"], a["view_share"]) == (b["mode"], b["view_share"])
    assert a["error"] == "foot" and b["error"] == ""


def test_few_frames_are_ambiguous_or_wrong_looking(indoor):
    """Error images and frames mixing two terrains about evenly: a few per cent."""
    bad = frames = 0
    for k in range(0, int(indoor.duration_s * 15), 2):
        f = indoor.render(k / 15)
        frames += 1
        bad += bool(f.truth["error"]) or f.truth["view_share"] < 0.6
    assert 0.05 < bad / frames < 0.25


# ---- error images --------------------------------------------------------------------------


def forced(kind: str, t: float = 2.0) -> tuple[DepthFrame, DepthFrame]:
    """The same moment rendered without and with an error image of `kind`."""
    course = make_course("indoor", 0)
    event = ErrorEvent(kind, t - 0.15, t + 0.15, 0.5, 11)
    plain = Simulator(course, seed=0, events=[]).render(t)
    return plain, Simulator(course, seed=0, events=[event]).render(t)


def test_error_image_foot_puts_something_near_the_lower_centre():
    plain, foot = forced("foot")
    assert foot.truth["error"] == "foot" and plain.truth["error"] == ""
    nearer = plain.xyz[..., 2] - foot.xyz[..., 2] > 0.1
    assert nearer[120:, 70:150].mean() > 0.3
    assert nearer[:40].mean() < 0.01  # the rest of the image is the same terrain


def test_error_image_occlusion_covers_the_centre_up_close():
    plain, occl = forced("occlusion")
    centre = occl.xyz[:, 100:124, 2]
    assert np.mean((centre > 0) & (centre < 1.0)) > 0.8
    assert np.mean(plain.xyz[..., 2] - occl.xyz[..., 2] > 0.1) > 0.3


def test_error_image_sky_loses_the_terrain():
    walk = Walk(make_course("indoor", 0))  # sky happens at peak flexion (a high knee lift)
    ts = np.linspace(1.5, 3.0, 300)
    plain, sky = forced("sky", t=float(ts[np.argmax(walk.flexion(ts))]))
    centre = slice(None), slice(80, 144)
    assert (sky.confidence[centre] > 0).mean() < 0.6 * (plain.confidence[centre] > 0).mean()
    axis_up = np.array(sky.truth["camera_pose"])[2, 2]  # world z of the optical axis
    assert axis_up > np.array(plain.truth["camera_pose"])[2, 2] + 0.3
    # the IMU sees the knee lift too: the thigh quaternion is part of the same walk
    assert sky.truth["thigh_quaternion"] != plain.truth["thigh_quaternion"]


def test_error_image_object_shows_a_clean_plane_instead_of_the_terrain():
    """An object's face fills the view: the leveled corridor shows one flat line at a tilt
    a terrain could have, above the ground the plain frame shows."""
    for t, strength in ((2.0, 0.5), (12.0, 0.2)):
        course = make_course("indoor", 0)
        event = ErrorEvent("object", t - 0.15, t + 0.15, strength, 11)
        plain = Simulator(course, seed=0, events=[]).render(t)
        shown = Simulator(course, seed=0, events=[event]).render(t)
        assert shown.truth["error"] == "object" and shown.truth["mode"] == plain.truth["mode"]
        p, q = leveled(shown), leveled(plain)
        corridor = p[(np.abs(p[:, 1]) < 0.05) & (p[:, 0] < 2.4)]
        assert len(corridor) > 100
        slope, height = np.polyfit(corridor[:, 0], corridor[:, 2], 1)
        residual = corridor[:, 2] - (slope * corridor[:, 0] + height)
        assert np.abs(residual).max() < 0.1  # one plane
        assert abs(np.degrees(np.arctan(slope))) < 17  # level or a ramp's tilt
        ground = q[(np.abs(q[:, 1]) < 0.05) & (q[:, 0] < 1.0)]
        assert np.median(corridor[:, 2]) > np.median(ground[:, 2])  # above the ground


def test_error_image_swing_blur_is_noisy_and_holed():
    plain, blur = forced("swing_blur", t=1.18)
    assert (blur.confidence > 0).mean() < 0.9 * (plain.confidence > 0).mean()

    def spread(f):
        p = leveled(f)
        return np.std(p[(np.abs(p[:, 1]) < 0.1) & (p[:, 0] < 1.5), 2])

    assert spread(blur) > 2 * spread(plain)


def test_bench_sim_frame_reports_milliseconds():
    from capture.bench.components import bench_sim_frame

    ms = bench_sim_frame(frames=3)
    assert 0 < ms < 1000
