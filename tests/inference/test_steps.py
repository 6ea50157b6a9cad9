"""Per-step metrics on hand-built decisions and gait events with known answers, and the
fusion that acts at steps (steady+steps) switching only at them."""

from __future__ import annotations

import numpy as np
import pytest

from inference.evaluation import steps as st
from inference.evaluation.metrics import evaluate_trial, run_offline
from inference.evaluation.trials import Trial, read_scores
from inference.fusion import make_fusion

LG, US, DS = 0, 1, 2


def _frames(n: int = 100) -> np.ndarray:
    return np.arange(n) / 10.0  # 10 fps: frame k at k/10 s


def test_decision_in_force_waits_for_the_delay():
    t = _frames(10)
    final = np.arange(10)  # frame k decides k
    # at 0.55 s the last frame is 5; with 1 frame of delay frame 4's decision is known
    assert st.decisions_in_force(t, final, 1, np.array([0.55, 0.0, 0.05])).tolist() == [4, -1, -1]
    assert st.decisions_in_force(t, final, 0, np.array([0.55])).tolist() == [5]


def test_heel_contact_and_toe_off_errors_transitions_and_leads():
    t = _frames(100)
    # steps: LG LG LG US US US LG LG LG LG at heel contacts 0.5, 1.5, ... 9.5 s
    hc = np.arange(10) + 0.5
    modes = np.array([LG, LG, LG, US, US, US, LG, LG, LG, LG])
    to = hc[:-1] + 0.3  # one toe off in each step: the swing lands at the next heel contact
    # decisions: US from frame 20 (2.0 s: before heel contact 2, one step early), back to
    # LG only from frame 70 (7.0 s: after heel contact 6, the transition step: late)
    final = np.full(100, LG)
    final[20:70] = US
    final[85] = US  # a glitch at heel contact 8 (8.5 s), far from any transition
    stats = st.step_stats(t, final, 0, st.Steps(hc, modes, to))
    assert stats.heel_contacts == 10
    # wrong at heel contacts 2 (US for LG), 6 (US for LG) and 8 (the glitch)
    assert stats.errors_at_heel_contact == 3
    assert stats.error_rate_at_heel_contact == pytest.approx(0.3)
    # toe offs at 0.8 .. 8.8 s need the next step's mode: wrong at 1.8 (US, needs LG),
    # at 5.8 (US, needs LG); 2.8 is US and needs US (right)
    assert stats.toe_offs == 9
    assert stats.errors_at_toe_off == 2
    assert stats.transition_steps == 2  # heel contacts 3 (to US) and 6 (to LG)
    assert stats.transition_steps_late == 1  # heel contact 6
    assert stats.lead_steps == [1, -1]  # US one heel contact early; LG one late
    assert stats.critical_errors == 1  # heel contact 8: 2 steps from transition 6


def test_unknown_modes_and_events_outside_the_frames_are_not_scored():
    t = _frames(50)
    hc = np.array([-1.0, 0.5, 1.5, 2.5, 9.0])  # the first and last outside the frames
    modes = np.array([LG, LG, -1, LG, LG])
    stats = st.step_stats(t, np.full(50, US), 0, st.Steps(hc, modes))
    assert stats.heel_contacts == 2  # 0.5 and 2.5 s
    assert stats.errors_at_heel_contact == 2
    assert stats.transition_steps == 0


def test_summary_and_pooled():
    t = _frames(30)
    a = st.step_stats(t, np.full(30, LG), 0, st.Steps([0.5, 1.5], [LG, US]))
    b = st.step_stats(t, np.full(30, LG), 0, st.Steps([0.5, 1.5, 2.5], [LG, LG, LG]))
    p = st.pooled([a, b])
    assert (p.heel_contacts, p.errors_at_heel_contact, p.transition_steps) == (5, 1, 1)
    s = st.summary(p)
    assert s["error_rate_at_heel_contact"] == pytest.approx(0.2)
    assert s["lead_steps"] == {"values": [None], "median": None}
    for key in ("heel_contacts", "error_rate_at_toe_off", "transition_steps_late"):
        assert key in s
    assert s["error_rate_at_toe_off"] is None  # no toe offs


def _probabilities(modes: np.ndarray, p: float = 0.9) -> np.ndarray:
    out = np.full((len(modes), 5), (1 - p) / 4)
    out[np.arange(len(modes)), modes] = p
    return out


DR = 4


def _heel_contacts(frames, n: int = 120) -> list[tuple[float, str]]:
    """Heel contacts at the given frames (10 fps), each with a toe off 10 frames later."""
    out = [(k / 10.0, "heel_contact") for k in frames]
    return sorted(out + [((k + 10) / 10.0, "toe_off") for k in frames if k + 10 < n])


def test_step_fusion_changes_at_the_heel_contact_before_the_new_terrain():
    n = 120
    truth = np.full(n, LG)
    truth[48:] = DR  # the terrain ahead changes at frame 48, late in a stride
    events = _heel_contacts(range(4, n, 16))
    probs = _probabilities(truth)
    run = run_offline(make_fusion("steady+steps"), probs, gait_events=events, times_s=_frames(n))
    # one switch, as the heel contact at frame 52 is handed over (its push decides frame 51)
    assert np.flatnonzero(np.diff(run.final)).tolist() == [50]
    assert run.final[-1] == DR
    # steady+hysteresis switches as the terrain ahead changes, mid-stride
    plain = run_offline(make_fusion("steady+hysteresis"), probs)
    assert np.flatnonzero(np.diff(plain.final)).tolist()[0] < 50


def test_step_fusion_drops_a_change_that_goes_back_before_its_step():
    n = 120
    read = np.full(n, LG)
    read[42:48] = DR  # 6 frames of another terrain, gone before the next heel contact
    events = _heel_contacts(range(4, n, 16))
    probs = _probabilities(read, 0.99)
    plain = run_offline(make_fusion("steady+hysteresis"), probs)
    assert len(np.flatnonzero(np.diff(plain.final))) == 2  # there and back
    # the camera level with the horizon: it shows terrain far ahead, a step away or more
    level = np.zeros(n)
    run = run_offline(
        make_fusion("steady+steps"), probs, level, gait_events=events, times_s=_frames(n)
    )
    assert (run.final == LG).all()


def test_step_fusion_drops_a_change_that_goes_back_without_an_elevation():
    # a score file has no camera elevation: a proposal counts as at the reference one
    n = 120
    read = np.full(n, LG)
    read[44:50] = DR  # late in the stride: heel contacts at frames 36 and 52
    events = _heel_contacts(range(4, n, 16))
    probs = _probabilities(read, 0.99)
    plain = run_offline(make_fusion("steady+hysteresis"), probs)
    assert len(np.flatnonzero(np.diff(plain.final))) == 2  # there and back
    for elevation in (None, np.full(n, np.nan)):
        run = run_offline(
            make_fusion("steady+steps"), probs, elevation, gait_events=events, times_s=_frames(n)
        )
        assert (run.final == LG).all()
    with pytest.raises(Exception, match="119 camera elevations"):
        run_offline(
            make_fusion("steady+steps"),
            probs,
            np.zeros(n - 1),
            gait_events=events,
            times_s=_frames(n),
        )


def test_step_fusion_times_a_change_by_the_decided_frames_elevation():
    # a push decides the frame before it: the elevation that counts is that frame's
    n = 120
    read = np.full(n, LG)
    read[42:] = DR  # the proposal holds its 2 decided frames at frame 43
    events = _heel_contacts(range(4, n, 16))
    probs = _probabilities(read, 0.99)

    def switch(level_frames: int) -> int:
        # every other frame level with the horizon (far ahead), the others steeply down
        elevation = np.where(np.arange(n) % 2 == level_frames, 0.0, -40.0)
        run = run_offline(
            make_fusion("steady+steps"), probs, elevation, gait_events=events, times_s=_frames(n)
        )
        return int(np.flatnonzero(np.diff(run.final))[0])

    assert switch(level_frames=1) == 50  # frame 43 looks far: the heel contact at frame 52
    assert switch(level_frames=0) == 42  # frame 43 looks down (frame 44, pushed, is level)


def test_step_fusion_waits_longer_for_a_change_seen_farther_ahead():
    n = 120
    read = np.full(n, LG)
    read[42:] = DR  # read mid-stride: heel contacts at frames 36 and 52
    events = _heel_contacts(range(4, n, 16))
    probs = _probabilities(read, 0.99)

    def switch(elevation_deg: float) -> int:
        run = run_offline(
            make_fusion("steady+steps"),
            probs,
            np.full(n, elevation_deg),
            gait_events=events,
            times_s=_frames(n),
        )
        return int(np.flatnonzero(np.diff(run.final))[0])

    # looking steeply down, the ramp is close: the next foot lands on it, so at once
    assert switch(-40.0) < 46
    # looking level, it is far: the change waits for the heel contact at frame 52
    assert switch(0.0) == 50


def test_step_fusion_ignores_a_misread_shorter_than_its_hold():
    n = 90
    read = np.full(n, LG)
    read[30] = US
    events = _heel_contacts(range(0, n, 16), n)
    run = run_offline(
        make_fusion("steady+steps"),
        _probabilities(read, 0.99),
        gait_events=events,
        times_s=_frames(n),
    )
    assert (run.final == LG).all()


def test_step_fusion_without_gait_events_still_switches():
    n = 120
    truth = np.full(n, LG)
    truth[40:] = US
    run = run_offline(make_fusion("steady+steps"), _probabilities(truth), gait_events=[])
    assert run.final[-1] == US  # after the stall, on its hold alone
    with pytest.raises(Exception, match="gait events"):
        run_offline(make_fusion("steady+steps"), _probabilities(truth))


def test_score_file_with_heel_contacts_is_scored_per_step(tmp_path):
    path = tmp_path / "s.csv"
    rows = ["LG,US,DS,UR,DR,label,locomotion,heel_contact,toe_off"]
    for k in range(60):
        label = "LG" if k < 30 else "US"
        locomotion = "LG" if k < 36 else "US"
        hc = "1" if k % 10 == 5 else "0"
        to = "1" if k % 10 == 0 else ""
        rows.append(f"0.9,0.025,0.025,0.025,0.025,{label},{locomotion},{hc},{to}")
    path.write_text("\n".join(rows) + "\n")
    trial = read_scores(path, fps=10)
    assert trial.steps.heel_contacts_s.tolist() == [0.5, 1.5, 2.5, 3.5, 4.5, 5.5]
    assert trial.steps.modes.tolist() == [LG, LG, LG, LG, US, US]  # the locomotion column's
    assert len(trial.gait_events) == 12
    result = evaluate_trial(trial, ["cnn", "steady+steps"])
    cnn = result.steps["cnn"]
    assert (cnn.heel_contacts, cnn.errors_at_heel_contact) == (6, 2)  # always LG
    assert cnn.transition_steps == 1 and cnn.transition_steps_late == 1
    # a study's evaluation drops each run once its figures are taken: the same figures
    lean = evaluate_trial(trial, ["cnn", "steady+steps"], keep_runs=False)
    assert lean.runs == {} and set(result.runs) == {"cnn", "steady+steps"}
    assert (lean.accuracy, lean.steps, lean.transitions) == (
        result.accuracy,
        result.steps,
        result.transitions,
    )


def test_score_file_event_column_must_be_zero_or_one(tmp_path):
    from inference.evaluation import ScoreFileError

    path = tmp_path / "s.csv"
    path.write_text("LG,US,DS,UR,DR,label,heel_contact\n1,0,0,0,0,LG,yes\n")
    with pytest.raises(ScoreFileError, match="heel_contact: expected 1"):
        read_scores(path)
    path.write_text("LG,US,DS,UR,DR,label,toe_off,heel_contact\n1,0,0,0,0,LG,0,1\n")
    with pytest.raises(ScoreFileError, match="in that order"):
        read_scores(path)


def test_trial_without_steps_has_no_step_figures():
    trial = Trial("t", _probabilities(np.zeros(20, dtype=int)), np.zeros(20, dtype=int))
    assert evaluate_trial(trial, ["cnn"]).steps == {}


def test_recorded_gait_events_give_steps_and_the_detected_cue():
    from devices.frames import GaitEvent
    from inference.evaluation.trials import gait_steps

    t0 = 10**9
    events = [
        GaitEvent(t0 + 500_000_000, "heel_contact", "simulator", "LG"),
        GaitEvent(t0 + 520_000_000, "heel_contact", "imu"),
        GaitEvent(t0 + 900_000_000, "toe_off", "simulator", "LG"),
        GaitEvent(t0 + 1_500_000_000, "heel_contact", "simulator", "US"),
    ]
    logged = [t0 + 500_000_000, t0 + 580_000_000, t0 + 900_000_000, t0 + 1_500_000_000]
    times = _frames(20)
    locomotion = np.zeros(20, dtype=int)
    steps, cue = gait_steps(events, t0, times, locomotion, logged)
    # the simulator's steps, with the terrain under the foot
    assert steps.source == "simulator" and steps.modes.tolist() == [LG, US]
    assert steps.heel_contacts_s.tolist() == pytest.approx([0.5, 1.5])
    assert steps.toe_offs_s.tolist() == pytest.approx([0.9])
    # the fusion gets the detector's event when it was detected (logged), not before
    assert cue == [(pytest.approx(0.58), "heel_contact")]
    # without the simulator's: the detector's heel contacts, with the live keys' mode
    steps, _ = gait_steps(events[1:2], t0, times, locomotion, logged[1:2])
    assert steps.source == "imu" and steps.mode_source == "locomotion"
    assert steps.heel_contacts_s.tolist() == pytest.approx([0.52]) and steps.modes.tolist() == [LG]


def test_bench_times_steady_steps_with_its_gait_events(monkeypatch):
    from capture.bench.components import bench_method_update
    from inference.fusion import METHOD_TABLE

    assert "steady+steps" in [m.name for m in METHOD_TABLE if m.bench_us]  # `walkcap bench`
    seen = []
    original = make_fusion

    def spying(method):
        fusion = original(method)
        see = fusion.see_gait
        fusion.see_gait = lambda event: (seen.append(event), see(event))
        return fusion

    monkeypatch.setattr("capture.bench.components.make_fusion", spying)
    assert bench_method_update("steady+steps", updates=200) > 0
    assert {"heel_contact", "toe_off"} <= set(seen)
