"""A frame whose IMU orientation is stale (the IMU unplugged or silent) gets no image and no
decision; the fusion holds; the frames are counted on screen, in `info`, in the export and
flagged the same way in replay."""

import json
import threading

import numpy as np
import pytest

from capture.config import Config, ConfigError, load
from capture.corpus import export
from capture.corpus.replay import replay
from capture.corpus.trials import read_trial
from capture.live.pipeline import OrientationTrack, Pipeline
from capture.live.preflight import CheckItem, PreflightReport
from capture.recording import topics as T
from capture.recording.reader import open_recording
from devices.frames import DepthFrame
from devices.simulator.synthetic import synthetic_frame
from inference.config import PreprocessConfig
from inference.fusion import make_fusion
from inference.preprocess import STALE_ORIENTATION, preprocess
from tests.tui.screens import FakeClock, StubClassifier, drill_app, rendered
from tests.waiting import wait_for_app
from tui.cli import main
from tui.live_screen import LiveScreen
from tui.replay import ReplaySource
from tui.widgets.decision import DecisionDisplay

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


class CountingFusion:
    """The real HMM, counting what it is fed."""

    def __init__(self) -> None:
        self.inner = make_fusion("hmm+voting", window=5, vote_delay=1)
        self.pushed = 0

    def push(self, probs):
        self.pushed += 1
        return self.inner.push(probs)


def nearest(times: np.ndarray, t: int) -> int:
    """Distance (ns) from `t` to the nearest of the sorted `times`."""
    j = int(np.searchsorted(times, t))
    return min(abs(int(times[k]) - t) for k in (j - 1, j) if 0 <= k < len(times))


def level_frame(index: int, time_ns: int) -> DepthFrame:
    return synthetic_frame(index, time_ns)


def test_an_orientation_older_than_the_bound_gives_no_image():
    frame = synthetic_frame(0, 0)
    params = PreprocessConfig()
    fresh = preprocess(frame.xyz, frame.confidence, LEVEL, params, orientation_age_ns=10_000_000)
    stale = preprocess(frame.xyz, frame.confidence, LEVEL, params, orientation_age_ns=60_000_000)
    assert stale.flag == STALE_ORIENTATION and not stale.image.any()
    assert fresh.flag != STALE_ORIENTATION
    bound = PreprocessConfig(max_orientation_age_ms=100.0)
    assert preprocess(frame.xyz, frame.confidence, LEVEL, bound, 60_000_000).flag == fresh.flag


def test_a_stale_frame_is_not_classified_and_the_fusion_holds():
    fusion = CountingFusion()
    pipeline = Pipeline(PreprocessConfig(), StubClassifier(), fusion)
    track = OrientationTrack()
    for k in range(10):  # 100 Hz, then silence: the IMU unplugged at 90 ms
        track.add(k * 10_000_000, LEVEL)
    results = []
    for k, t in enumerate((50_000_000, 85_000_000, 400_000_000, 900_000_000)):
        q, age = track.at(t)
        results.append(pipeline.process(level_frame(k, t), q, t, orientation_age_ns=age))
    assert [r.flag == STALE_ORIENTATION for r in results] == [False, False, True, True]
    assert [r.decided for r in results] == [True, True, False, False]
    assert fusion.pushed == 2  # held: the stale frames never reach the HMM
    assert all(r.fused is None and np.isnan(r.probabilities).all() for r in results[2:])


def test_the_bound_is_configurable_and_checked(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text("[preprocess]\nmax_orientation_age_ms = 80.0\n")
    config = load(str(path))
    assert config.preprocess.max_orientation_age_ms == 80.0
    path.write_text("[preprocess]\nmax_orientation_age_ms = 0.0\n")
    with pytest.raises(ConfigError, match="max_orientation_age_ms"):
        load(str(path))


@pytest.mark.realtime
@pytest.mark.slow
async def test_the_tui_unplug_drill_flags_the_frames_everywhere(tmp_path, busy_pilot, capsys):
    config = Config()
    config.session.recordings = str(tmp_path / "recordings")
    sessions = []
    app = drill_app(
        config,
        sessions,
        preflight=lambda session: PreflightReport([CheckItem("disk", True, "ok", "")]),
    )
    seen_unknown = []
    async with app.run_test(size=(120, 40)) as pilot:
        await wait_for_app(pilot, lambda: app.ready, 15)
        session = sessions[0]
        await wait_for_app(pilot, lambda: session.snapshot().frames >= 5, 10)
        await pilot.press("1", "r")
        await wait_for_app(pilot, lambda: app.recording_path is not None, 5)
        await wait_for_app(pilot, lambda: session.snapshot().frames >= 20, 10)
        await pilot.press("ctrl+u")  # drill: the IMU unplugged for 2 s
        live = app.screen
        assert isinstance(live, LiveScreen)
        decision = live.query_one(DecisionDisplay)

        def unknown_shown():
            text = str(decision.render().renderables[1])
            if "unknown" in text:
                seen_unknown.append(text)
            return bool(seen_unknown)

        await wait_for_app(pilot, unknown_shown, 10)
        await wait_for_app(pilot, lambda: session.snapshot().stale_frames >= 15, 10)
        panel = live.query_one("#devices")
        await wait_for_app(pilot, lambda: "frames (old IMU)" in rendered(panel), 5)
        await wait_for_app(pilot, lambda: session.alarms.counters["imu"].longest_s > 1.5, 10)
        await wait_for_app(pilot, lambda: session.snapshot().latest.decided, 10)  # IMU back
        await pilot.press("r")
        await wait_for_app(pilot, lambda: app.recording_path is None and not session.recording, 5)
        on_screen = session.snapshot().stale_frames
        await pilot.press("q")
        await wait_for_app(pilot, lambda: not app.is_running, 5)
    assert "unknown: IMU orientation stale" in seen_unknown[0]
    (path,) = (tmp_path / "recordings").glob("S09_*.mcap")
    rec = open_recording(path)
    pre = {m.data["frame_index"]: m.data for m in rec.messages([T.PREPROCESS])}
    stale = sorted(i for i, d in pre.items() if d["flag"] == STALE_ORIENTATION)
    # the frames the file itself has no orientation for: farther than the bound from every
    # IMU sample recorded (the unplugged span)
    imu = np.sort([m.data["time_ns"] for m in rec.messages([T.IMU]) if m.data.get("quaternion")])
    in_gap = sorted(i for i, d in pre.items() if nearest(imu, d["time_ns"]) > 50_000_000)
    assert len(in_gap) >= 15  # ~2 s at 15 fps
    assert set(in_gap) <= set(stale) and len(stale) <= on_screen  # flagged, counted on screen
    decided = set(read_trial(path).frames.index.tolist())
    assert not decided & set(stale)  # no CNN output for a stale frame
    fused = [m.data for m in rec.messages([T.FUSED])]
    assert not {d["frame_index"] for d in fused} & set(stale)  # nor a fused decision
    # `info`, text and JSON, and the export count the same frames
    assert main(["info", str(path)]) == 0
    assert f"stale orientation {len(stale)}, bad orientation 0 (no image" in capsys.readouterr().out
    assert main(["info", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)[0]["stale_orientation_frames"] == len(stale)
    tables = export.tables(path)
    assert int(tables["trials"]["stale_orientation_frames"][0]) == len(stale)
    frames = tables["frames"].set_index("frame_index")
    assert (frames.loc[stale, "preprocess_flag"] == STALE_ORIENTATION).all()
    assert (frames.loc[stale, "cnn_decision"] == "").all()
    # the review screen (replay --tui) shows them as the live one did: undecided, counted
    source = ReplaySource(path, clock=(clock := FakeClock()))
    source.start()
    times = {m.data["frame_index"]: m.data["time_ns"] for m in rec.messages([T.PREPROCESS])}
    # a millisecond past the frame: the cursor is on it, not on the one before
    middle = in_gap[len(in_gap) // 2]
    clock.t += times[middle] - int(source.frames.time_ns[0]) + 1_000_000
    snap = source.snapshot()
    assert snap.latest.index == middle and snap.latest.flag == STALE_ORIENTATION
    assert not snap.latest.decided and 0 < snap.stale_frames < len(stale)
    # replay flags the frames of the gap too (it interpolates across it: older than the bound)
    report = replay(str(path), Config(), classifier=StubClassifier(), output=tmp_path / "r.mcap")
    again = open_recording(report.output)
    replayed = {
        m.data["frame_index"]
        for m in again.messages([T.PREPROCESS])
        if m.data["flag"] == STALE_ORIENTATION
    }
    assert set(in_gap) <= replayed  # every frame of the unplugged span, with no decision
    assert not set(read_trial(report.output).frames.index.tolist()) & replayed


def test_a_late_imu_is_waited_for_and_a_silent_one_is_not():
    clock = FakeClock()
    track = OrientationTrack(clock=clock)
    for k in range(10):  # 100 Hz up to 90 ms
        track.add(k * 10_000_000, LEVEL)
    frame_t, bound = 200_000_000, 50_000_000
    # silent for longer than a late IMU would be: stale at once, without waiting
    clock.t = int(10 * 1e9)
    q, age = track.fresh_at(frame_t, bound, late_s=5.0)
    assert age > bound
    # samples still coming (a busy host delays them): the frame waits for them
    clock.t = track_added = int(10 * 1e9)
    track.add(100_000_000, LEVEL)
    assert track._added_ns == track_added
    late = threading.Thread(
        target=lambda: [track.add(k * 10_000_000, LEVEL) for k in range(11, 21)]
    )
    late.start()
    q, age = track.fresh_at(frame_t, bound, late_s=60.0)  # generous: never reached
    late.join()
    assert age <= bound and q is not None


class CountingClassifier(StubClassifier):
    def __init__(self) -> None:
        self.seen = 0

    def predict(self, image):
        self.seen += 1
        return super().predict(image)


def test_a_bad_orientation_frame_is_left_undecided_and_counted_in_info(tmp_path, capsys):
    """A quaternion that is no rotation (none at all, or NaN): no image to classify, so no
    CNN output and no decision, the fusion held, as for a stale one; info counts them."""
    from capture.live.pipeline import record_result
    from capture.recording.writer import Recorder
    from inference.preprocess import BAD_ORIENTATION

    fusion, classifier = CountingFusion(), CountingClassifier()
    pipeline = Pipeline(PreprocessConfig(), classifier, fusion)
    bad = np.full(4, np.nan)
    quaternions = [LEVEL, None, bad, LEVEL, np.zeros(4)]
    path = tmp_path / "trial.mcap"
    with Recorder(path, metadata={}, blocking=True) as recorder:
        results = []
        for k, q in enumerate(quaternions):
            frame = level_frame(k, (k + 1) * 66_000_000)
            results.append(pipeline.process(frame, q, frame.device_time_ns))
            record_result(recorder, frame, results[-1], frame.host_time_ns)
    assert [r.flag == BAD_ORIENTATION for r in results] == [False, True, True, False, True]
    assert [r.decided for r in results] == [True, False, False, True, False]
    assert fusion.pushed == 2 and classifier.seen == 2  # the CNN never saw the bad frames
    assert all(r.fused is None and np.isnan(r.probabilities).all() for r in results[1:3])
    assert set(read_trial(path).frames.index.tolist()) == {0, 3}
    assert main(["info", str(path)]) == 0
    assert "stale orientation 0, bad orientation 3 (no image, no decision)" in (
        capsys.readouterr().out
    )
    assert main(["info", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)[0]["bad_orientation_frames"] == 3
