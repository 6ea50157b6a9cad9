"""A recording made with the step fusion: the live pipeline got the detector's gait events
as eval hands them over, so offline decisions repeat the live ones."""

from dataclasses import replace

import numpy as np
import pytest

from capture.corpus.trials import read_evaluation_trial, read_trial
from tests.recording_fixtures import synth_recording


@pytest.mark.slow
def test_steady_steps_decides_offline_as_it_decided_live(tmp_path):
    from inference.evaluation.metrics import run_trial
    from inference.fusion import make_fusion

    path = synth_recording(tmp_path, "steady+steps", "indoor", 120)
    recorded = read_trial(path)
    live = recorded.frames.decision
    trial = read_evaluation_trial(path)
    assert sum(1 for _, e in trial.gait_events if e == "heel_contact") >= 5  # 8 s walking
    assert len(set(live[live >= 0].tolist())) > 1  # it changed its mode at least once
    offline = run_trial(make_fusion("steady+steps"), trial)
    np.testing.assert_array_equal(offline.final[live >= 0], live[live >= 0])
    # without the events the schedule differs: the test would see a broken hand-over
    alone = run_trial(make_fusion("steady+steps"), replace(trial, gait_events=[]))
    assert not np.array_equal(alone.final[live >= 0], live[live >= 0])
