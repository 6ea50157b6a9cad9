"""The simulator's gait truth: a heel contact and a toe off of the instrumented leg each
stride, on every terrain (curbs outdoors too), placed on the thigh's swing, with the mode
under that foot; none standing; and the mock camera hands them out with its frames."""

from __future__ import annotations

import numpy as np
import pytest

from devices.config import SimulatorConfig
from devices.simulator import Simulator, make_course
from devices.simulator.camera import MockCamera
from devices.simulator.walk import HEEL_CONTACT_PHASE, STANCE_SHARE


@pytest.fixture(scope="module", params=["indoor", "outdoor"])
def sim(request):
    return Simulator(make_course(request.param, 4), seed=4)


def _events(sim):
    return sim.gait_truth(-1.0, sim.duration_s, 0)  # stamped: 0 at the walk's end


def test_every_stride_has_a_heel_contact_then_a_toe_off(sim):
    events = _events(sim)
    kinds = [e.event for e in events]
    assert kinds == ["heel_contact", "toe_off"] * (len(kinds) // 2)
    strides = round(sim.walk.phase(sim.duration_s) / (2 * np.pi))  # it ends a whole stride
    assert len(kinds) // 2 == strides
    assert {e.source for e in events} == {"simulator"}
    t = np.array([e.time_ns for e in events]) * 1e-9 + sim.duration_s  # walk time
    assert t.min() > 0 and t.max() <= sim.duration_s  # none outside the walk


def test_events_sit_on_the_swing_stance_takes_sixty_percent(sim):
    events = _events(sim)
    t = np.array([e.time_ns for e in events]) * 1e-9 + sim.duration_s
    phase = sim.walk.phase(t) % (2 * np.pi)
    # heel contact a twentieth of a stride after the thigh's peak flexion: at pi / 2 of
    # the swing, but where the swing's size changes (a terrain's) or a knee lift moves it
    contact = sim.walk.phase(t[0::2])
    peak = np.interp(contact - (HEEL_CONTACT_PHASE - np.pi / 2), sim.walk._phase, sim.walk._t)
    for dt in (-0.04, 0.04):
        assert np.all(sim.walk.flexion(peak) >= sim.walk.flexion(peak + dt))
    assert np.mean(np.isclose(contact % (2 * np.pi), HEEL_CONTACT_PHASE, atol=0.03)) > 0.7
    stance = (phase[1::2] - HEEL_CONTACT_PHASE) % (2 * np.pi) / (2 * np.pi)
    assert np.allclose(stance, STANCE_SHARE, atol=0.01)
    # the thigh is extending at heel contact, flexing at toe off
    rate = [sim.walk.flexion_rate(float(x)) for x in t]
    assert all(r < 0 for r in rate[0::2]) and all(r > 0 for r in rate[1::2])


def test_each_event_names_the_terrain_under_its_foot(sim):
    events = _events(sim)
    seen = {e.mode for e in events}
    assert seen == set(sim.course.modes)  # level, stairs up and down, ramps up and down
    # a foot stands where it landed: its toe off has its heel contact's terrain
    assert all(a.mode == b.mode for a, b in zip(events[0::2], events[1::2]))
    # the foot lands ahead of the hip: on entering stairs, the contact is on the stairs
    # while the hip is still on the floor before them
    hip = [
        sim.locomotion_mode(e.time_ns * 1e-9 + sim.duration_s)
        for e in events
        if e.event == "heel_contact"
    ]
    foot = [e.mode for e in events if e.event == "heel_contact"]
    assert any(h != f for h, f in zip(hip, foot))


def test_curbs_outdoors_are_level_ground_under_the_foot():
    course = make_course("outdoor", 4)
    curbs = [(x, seg) for seg in course.segments for x, _ in seg.curbs]
    assert curbs  # the outdoor course has curbs
    sim = Simulator(course, seed=4)
    x = [
        float(sim.walk.position(e.time_ns * 1e-9 + sim.duration_s))
        for e in _events(sim)
        if e.event == "heel_contact"
    ]
    assert len(x) > 2
    near_curb = [
        e.mode
        for e, xe in zip([e for e in _events(sim) if e.event == "heel_contact"], x)
        if any(abs(xe - cx) < 1.0 and seg.mode == "LG" for cx, seg in curbs)
    ]
    assert near_curb and set(near_curb) == {"LG"}


def test_the_mock_camera_hands_the_events_out_with_its_frames_and_none_standing():
    config = SimulatorConfig(course="indoor", seed=4, realtime=False)
    camera = MockCamera(simulator_config=config, realtime=False)
    got = []
    k = 0
    for k in range(60):  # four seconds at 15 fps, rendered in order as _produce does
        t = k / 15
        frame = camera.simulator.render(camera.walk_time(t), index=k)
        frame.device_time_ns = 10**12 + int(round(t * 1e9))
        camera._add_gait_truth(frame, camera.walk_time(t))
        got += frame.truth.get("gait", [])
        if frame.truth.get("gait"):
            assert all(e.time_ns <= frame.device_time_ns for e in frame.truth["gait"])
    want = camera.simulator.gait_truth(-1.0, k / 15, 10**12 + int(round(k / 15 * 1e9)))
    assert [(e.event, e.mode) for e in got] == [(e.event, e.mode) for e in want]
    assert np.allclose([e.time_ns for e in got], [e.time_ns for e in want], atol=1000)
    assert len(got) >= 4
    standing = MockCamera(simulator_config=SimulatorConfig(stand=True), realtime=False)
    frame = standing.simulator.render(standing.walk_time(2.0))
    standing._add_gait_truth(frame, standing.walk_time(2.0))
    assert "gait" not in frame.truth


@pytest.mark.parametrize(("preset", "seed"), [("indoor", 4), ("indoor", 11), ("outdoor", 5)])
def test_on_stairs_each_foot_lands_in_the_middle_of_a_tread(preset, seed):
    """A walker puts one foot a tread, the whole foot on it: no heel contact lands across
    a riser or a nosing, and the stride before the stairs is fitted so that the first foot
    lands on the first tread."""
    course = make_course(preset, seed)
    sim = Simulator(course, seed=seed, speed_mps=1.3, cadence_spm=95.0)  # a long stride
    events = sim.walk.gait_events(-1.0, sim.duration_s)
    feet = [x for _, event, x in events if event == "heel_contact"]
    stairs = [s for s in course.segments if s.mode in ("US", "DS")]
    on_stairs = 0
    for seg in stairs:
        for x in feet:
            if seg.x0 <= x < seg.x0 + seg.steps * seg.tread_m:
                on_stairs += 1
                tread, place = divmod((x - seg.x0) / seg.tread_m, 1.0)  # place 0.5: the middle
                if tread < seg.steps - 1:
                    assert abs(place - 0.5) < 0.25, (seg.mode, x, place)
                else:  # the floor the stairs lead to: clear of the last riser or nosing
                    assert place > 0.25, (seg.mode, x, place)
        before = max(x for x in feet if x < seg.x0)
        assert seg.x0 - before > 0.5 * seg.tread_m  # the last foot on the floor stays clear
    assert on_stairs >= len(stairs)
    # the walk goes on, forward only
    assert np.all(np.diff(sim.walk._phase) > 0)
