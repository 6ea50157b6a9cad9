"""The thigh-IMU gait-event detector on synthetic signals: a heel contact and a toe off a
stride while walking, none standing, shifting weight or turning on the spot, none placed
in or across an IMU gap; and the one-to-one matching eval gait scores with."""

from __future__ import annotations

import numpy as np

from devices.frames import ImuSample
from devices.rotations import quat_from_euler
from inference.gait import GaitDetector, GaitParams, detect, match_events, score_events

RATE = 100.0
STRIDE_S = 1.2


def samples(flexion, yaw=None, seconds=12.0, rate=RATE, drop=None, seed=0):
    """ImuSamples of a thigh whose flexion (rad) and heading follow the given functions of
    t; rate of turn by differences, with gyro noise; `drop`: (t0, t1) of samples lost."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate)) / rate
    flex = flexion(t)
    heading = yaw(t) if yaw is not None else np.zeros_like(t)
    quats = np.moveaxis(quat_from_euler(np.zeros_like(t), -flex, heading), 0, -1)
    d_flex, d_yaw = np.gradient(flex, t), np.gradient(heading, t)
    out = []
    for k, tk in enumerate(t):
        if drop is not None and drop[0] <= tk < drop[1]:
            continue
        q = quats[k]
        # body rates: flexion about -y; a turn about the world's vertical, felt mostly on z
        gyro = np.array([0.0, -d_flex[k], d_yaw[k]]) + rng.normal(0, 0.01, 3)
        ns = int(round(tk * 1e9))
        out.append(ImuSample(ns + 3_000_000, ns, k % 65536, None, np.asarray(q), None, gyro, 0))
    return out


def walking(t):
    return np.radians(8 + 19 * np.sin(2 * np.pi * t / STRIDE_S))


def peaks(seconds=12.0):
    """Peak flexion times of `walking`: a quarter stride into each stride."""
    return np.arange(STRIDE_S / 4, seconds, STRIDE_S)


def test_walking_gives_a_heel_contact_after_each_peak_flexion_and_a_toe_off_after_each_stance():
    events = detect(samples(walking))
    params = GaitParams()
    contacts = np.array([e.time_ns for e in events if e.event == "heel_contact"]) * 1e-9
    offs = np.array([e.time_ns for e in events if e.event == "toe_off"]) * 1e-9
    expected = peaks() + params.heel_contact_lag * STRIDE_S
    # the first swing is seen from mid-swing on and counts; every later one too
    assert len(contacts) == len(expected)
    # the stride is assumed until two are seen, then measured: the first lag is off a little
    assert np.max(np.abs(contacts[1:] - expected[1:])) < 0.015
    assert np.abs(contacts[0] - expected[0]) < 0.03
    # toe off: after peak extension (half a stride after peak flexion), once a stance began
    troughs = peaks() + STRIDE_S / 2
    troughs = troughs[troughs < 12.0 - 0.2]
    assert np.max(np.abs(offs - (troughs + params.toe_off_lag * STRIDE_S))) < 0.03
    assert [e.event for e in events][:4] == ["heel_contact", "toe_off"] * 2
    assert {e.source for e in events} == {"imu"} and {e.mode for e in events} == {None}


def test_standing_still_shifting_weight_or_turning_on_the_spot_gives_no_event():
    still = samples(lambda t: np.full_like(t, np.radians(3.0)))
    sway = samples(lambda t: np.radians(3 + 3 * np.sin(2 * np.pi * 0.4 * t)))
    turn = samples(lambda t: np.radians(2 + 0 * t), yaw=lambda t: 1.5 * np.sin(0.8 * t))
    for stream in (still, sway, turn):
        assert detect(stream) == []


def test_walking_while_turning_gives_the_same_steps():
    straight = detect(samples(walking))
    turning = detect(samples(walking, yaw=lambda t: 0.6 * t))  # a full circle in 10 s
    assert [e.event for e in turning] == [e.event for e in straight]
    diff = np.array([a.time_ns - b.time_ns for a, b in zip(turning, straight, strict=True)])
    assert np.max(np.abs(diff)) < 10_000_000


def test_no_event_is_placed_in_or_right_after_a_gap():
    whole = detect(samples(walking))
    contact = [e.time_ns * 1e-9 for e in whole if e.event == "heel_contact"][3]
    # the samples from just before the peak flexion to past the heel contact are lost
    gap = (contact - 0.2, contact + 0.1)
    events = detect(samples(walking, drop=gap))
    times = np.array([e.time_ns for e in events]) * 1e-9
    assert not np.any((times >= gap[0]) & (times < gap[1]))
    # the stride the gap cut has no heel contact at all (its swing was not seen whole) ...
    contacts = [e.time_ns * 1e-9 for e in events if e.event == "heel_contact"]
    assert not any(gap[1] <= c < gap[1] + 0.5 for c in contacts)
    # ... and the strides after it have theirs, where they were without the gap
    later = [c for c in contacts if c > gap[1] + 0.5]
    expected = [
        e.time_ns * 1e-9
        for e in whole
        if e.event == "heel_contact" and e.time_ns * 1e-9 > gap[1] + 0.5
    ]
    assert np.allclose(later, expected, atol=0.02)


def test_samples_the_packet_counter_misses_are_a_gap_when_they_last():
    stream = samples(walking)

    def gaps(lost: int) -> int:
        detector = GaitDetector()
        for s in stream[:300] + stream[300 + lost :]:
            detector.push(s)
        return detector.gaps

    assert gaps(0) == 0 and gaps(1) == 0  # a sample lost: 20 ms, the swing still seen
    assert gaps(3) == 1  # 40 ms with three samples missing: a gap


def test_cadence_while_walking_and_none_once_standing():
    detector = GaitDetector()
    for s in samples(walking):
        detector.push(s)
    assert abs(detector.cadence_spm() - 120 / STRIDE_S) < 1.0
    assert detector.heel_contacts == len(peaks())
    assert detector.cadence_spm(detector.last_time_ns + 10_000_000_000) is None


def test_matching_is_one_to_one_within_the_tolerance():
    truth = [1_000, 2_000, 3_000]
    found = [1_010, 1_020, 2_100, 2_990]
    assert match_events(truth, found, 50) == [(0, 0), (2, 3)]
    score = score_events(truth, found, 50)
    assert (score.true, score.detected, score.matched) == (3, 4, 2)
    assert score.recall == 2 / 3 and score.precision == 0.5
    assert np.allclose(score.errors_ms, (10e-6, -10e-6))


def test_a_noisy_gyroscope_makes_no_extra_event():
    clean = detect(samples(walking))
    noisy = samples(walking, seed=3)
    rng = np.random.default_rng(5)
    for s in noisy:  # 0.2 rad/s (11 deg/s) of white noise, far beyond an MTi's
        s.rate_of_turn[1] += rng.normal(0, 0.2)
    events = detect(noisy)
    assert [e.event for e in events] == [e.event for e in clean]
    diff = np.array([a.time_ns - b.time_ns for a, b in zip(events, clean, strict=True)])
    assert np.max(np.abs(diff)) < 30_000_000
