"""Transition metrics on hand-made sequences with known answers."""

import numpy as np
import pytest

from inference.evaluation.transitions import (
    Change,
    decision_switches,
    settled_changes,
    summary,
    transition_stats,
)

FPS = 10.0  # 0.1 s a frame: times easy to read


def seq(*runs: tuple[int, int]) -> np.ndarray:
    """(mode, frames) runs as one per-frame sequence."""
    return np.concatenate([np.full(n, m) for m, n in runs])


def test_settled_changes_ignore_glances_shorter_than_a_step():
    # LG 20, US 2 (a glance), LG 3, US 30: one change, at the start of the run that settles
    ref = seq((0, 20), (1, 2), (0, 3), (1, 30))
    t = np.arange(len(ref)) / FPS
    assert settled_changes(ref, t, min_dwell_s=0.5) == [Change(25, 0, 1)]
    # with no dwell, every flip is a change
    assert len(settled_changes(ref, t, min_dwell_s=0.0)) == 3


def test_settled_changes_skip_unlabelled_frames_and_keep_the_last_run():
    ref = seq((-1, 5), (0, 10), (-1, 4), (0, 6), (2, 3))  # last run short but at the end
    t = np.arange(len(ref)) / FPS
    assert settled_changes(ref, t, 0.5) == [Change(25, 0, 2)]


def test_decision_switches_skip_undecided_frames():
    d = np.array([-1, 0, 0, -1, 0, 1, 1, -1, 2])
    assert decision_switches(d) == [Change(5, 0, 1), Change(8, 1, 2)]


def test_a_clean_switch_is_matched_with_its_delay_and_nothing_is_spurious():
    ref = seq((0, 50), (1, 50))
    dec = seq((0, 52), (1, 48))  # switches 2 frames late
    s = transition_stats(dec, ref, fps=FPS, delay_frames=1)
    assert (s.changes, s.switches, s.matched, s.missed, s.spurious) == (1, 1, 1, 0, 0)
    assert s.delays_frames == [3]  # 2 frames late + known 1 frame after its frame
    assert s.delays_s == pytest.approx([0.3])
    assert s.minutes == pytest.approx(10.0 / 60)
    assert summary(s)["delay_ms"]["median"] == pytest.approx(300.0)


def test_flicker_counts_spurious_switches_per_minute():
    ref = seq((0, 300), (3, 300))  # one change in 60 s
    dec = ref.copy()
    dec[100] = 2  # LG -> DS -> LG: two spurious switches
    dec[400:402] = 0  # UR -> LG -> UR: two more
    s = transition_stats(dec, ref, fps=FPS)
    assert (s.changes, s.switches, s.matched, s.missed, s.spurious) == (1, 5, 1, 0, 4)
    assert s.spurious_per_min == pytest.approx(4.0)


def test_a_switch_to_the_wrong_mode_or_too_late_is_a_miss_and_spurious():
    ref = seq((0, 50), (1, 100))
    wrong = seq((0, 50), (3, 100))  # switched, but to up ramp
    s = transition_stats(wrong, ref, fps=FPS)
    assert (s.matched, s.missed, s.spurious) == (0, 1, 1)
    late = seq((0, 80), (1, 70))  # 3 s after the change: outside the 2 s window
    s = transition_stats(late, ref, fps=FPS)
    assert (s.matched, s.missed, s.spurious) == (0, 1, 1)


def test_each_switch_matches_one_change_the_nearest():
    # LG -> US -> LG -> US, each held long: three changes; the decision makes all three
    ref = seq((0, 40), (1, 40), (0, 40), (1, 40))
    dec = seq((0, 38), (1, 44), (0, 40), (1, 38))
    s = transition_stats(dec, ref, fps=FPS)
    assert (s.matched, s.missed, s.spurious) == (3, 0, 0)
    assert s.delays_frames == [-2, 2, 2]


def test_lead_time_against_the_locomotion_reference():
    # the subject steps onto stairs at 10 s, 12 s is the next change back to level
    loco = seq((0, 100), (1, 100), (0, 100))
    dec = seq((0, 90), (1, 110), (0, 100))  # 1 s before the step up, on time for the step down
    s = transition_stats(dec, loco, name="locomotion", fps=FPS, delay_frames=1)
    assert s.lead_times_s == pytest.approx([0.9, -0.1])
    assert s.late == 1
    out = summary(s)
    assert out["reference"] == "locomotion" and out["late"] == 1
    assert out["lead_ms"]["median"] == pytest.approx(400.0)
    # numpy percentile, linear: -100 ms + 10 % of the 1000 ms between the two
    assert out["lead_ms"]["p10"] == pytest.approx(0.0, abs=1e-6)
    # the locomotion window reaches 3 s before the change, the terrain window 2 s
    early = seq((0, 75), (1, 125))
    assert transition_stats(early, seq((0, 100), (1, 100)), name="locomotion", fps=FPS).matched == 1
    assert transition_stats(early, seq((0, 100), (1, 100)), name="terrain", fps=FPS).matched == 0


def test_frame_times_are_used_when_given():
    ref = seq((0, 10), (1, 10))
    times = np.r_[np.arange(10) * 0.1, 5.0 + np.arange(10) * 0.1]  # a 4 s gap
    dec = seq((0, 11), (1, 9))
    s = transition_stats(dec, ref, times, min_dwell_s=0.5)
    assert s.delays_s == pytest.approx([0.1])


def test_following_a_glance_is_not_spurious_and_ignoring_it_is_not_missed():
    # terrain: LG, a 2-frame glance at US, LG, then US for good
    ref = seq((0, 30), (1, 2), (0, 8), (1, 40))
    follower = transition_stats(ref.copy(), ref, fps=FPS)  # follows every flip
    assert (follower.changes, follower.switches, follower.missed, follower.spurious) == (1, 3, 0, 0)
    once = transition_stats(seq((0, 30), (1, 50)), ref, fps=FPS)  # switches once, early
    assert (once.switches, once.matched, once.missed, once.spurious) == (1, 1, 0, 0)
    assert once.delays_frames == [-10]
    # a flip to a mode the terrain never showed nearby is spurious
    wrong = ref.copy()
    wrong[60:62] = 3
    assert transition_stats(wrong, ref, fps=FPS).spurious == 2
