"""Replay in the UI: a recording plays in the live screens; label corrections go to a new
file, message for message the original plus the corrections; the original never changes."""

import hashlib

import numpy as np
import pytest

from capture.config import Config
from capture.corpus.trials import read_trial
from capture.live.trials import SubjectInfo
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from devices.base import DeviceEvent
from devices.frames import MODES
from tests.tui.screens import FakeClock
from tests.waiting import wait_for_app
from tui.app import WalkcapApp
from tui.live_screen import LiveScreen
from tui.replay import ReplaySource, corrected_path, write_corrected
from tui.widgets.quit_dialog import QuitDialog

FPS = 15
N = 60  # 4 s
T0 = 5_000_000_000


def frame_time(i: int) -> int:
    return T0 + int(i * 1e9 / FPS)


@pytest.fixture
def recording(tmp_path):
    """Level ground for 2 s, then up stairs; the operator pressed US 0.5 s late."""
    path = tmp_path / "S05_indoor_t03.mcap"
    meta = {
        "session": SubjectInfo(subject="S05", trial=3).to_metadata(),
        "devices": {
            "camera_backend": "mock",
            "camera_fps": "15.0",
            "imu_backend": "mock",
            "imu_rate_hz": "100",
        },
    }
    rec = Recorder(path, metadata=meta)
    rec.start()
    rec.write_label(T0, "LG", "start")
    for i in range(N):
        t = frame_time(i)
        true = 0 if i < 30 else 1
        image = np.zeros((100, 100), np.uint8)
        image[60 - 20 * true :, 10:90] = 1
        cloud = np.column_stack(
            [np.linspace(0.1, 1.4, 50), np.zeros(50), np.full(50, -0.5 + 0.1 * true)]
        ).astype(np.float32)
        probs = np.full(5, 0.05)
        probs[true] = 0.8
        fused = {"frame_index": i - 1, "decision": MODES[true]} if i else {}
        rec.write_processed(i, t, t + 1_000_000, cloud, image, np.array([1.0, 0, 0, 0]), "")
        rec.write_inference(i, t, t + 2_000_000, probs, fused)
        rec.write_features(i, t, {"kind": "stairs" if true else "level", "slope_deg": 0.0})
        rec.write_truth(i, t, {"mode": MODES[true]})
    rec.write_label(frame_time(37), "US", "operator")
    rec.write_event(DeviceEvent(frame_time(10), "imu", "checksum_error", "1 bad message"))
    rec.close()
    return path


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_replay_source_plays_seeks_and_corrects(recording):
    clock = FakeClock()
    source = ReplaySource(recording, clock=clock)
    source.start()
    assert source.playing and source.duration_s == pytest.approx((N - 1) / FPS)
    assert source.subject_info.subject == "S05" and source.subject_info.trial == 3
    snap = source.snapshot()
    assert snap.latest.index == 0 and snap.label == "LG" and snap.latest.image.sum() > 0
    clock.t += 1_000_000_000  # one second of playing
    snap = source.snapshot()
    assert snap.latest.index == 15 and snap.time_ns == frame_time(15)
    assert len(snap.timeline) == 16 and snap.timeline[-1].truth == "LG"
    assert [e.kind for e in snap.events] == ["checksum_error"]
    source.toggle_play()  # pause
    clock.t += 5_000_000_000
    assert source.snapshot().latest.index == 15
    source.seek(1.0)  # to 2 s: the stairs begin, the operator's US comes at frame 37
    snap = source.snapshot()
    assert snap.latest.index == 30 and snap.label == "LG" and snap.latest.cnn_decision == 1
    assert snap.latest.fused.decision == 1 and snap.latest.features["kind"] == "stairs"
    assert snap.latest.profile.shape[1] == 2 and snap.latest.profile[0, 1] == pytest.approx(
        -0.4, abs=1e-3
    )
    source.set_label("US")  # the correction: stairs from frame 30
    assert source.label == "US" and source.unsaved
    source.seek(-10)
    assert source.snapshot().latest.index == 0
    source.seek(100)
    snap = source.snapshot()
    assert snap.latest.index == N - 1 and snap.timeline[-1].label == "US"
    assert [e.label for e in snap.timeline].count("US") == N - 30
    source.undo_label()
    assert [e.label for e in source.snapshot().timeline].count("US") == N - 37


def test_corrections_go_to_a_new_file_and_the_original_is_untouched(recording):
    before = digest(recording)
    source = ReplaySource(recording, clock=FakeClock(), play=False)
    source.start()
    source.seek(2.0)
    source.set_label("US")
    source.add_marker("stairs start here")
    assert corrected_path(recording) == recording.with_name("S05_indoor_t03_corrected.mcap")
    out = source.save_corrections()
    assert out == recording.with_name("S05_indoor_t03_corrected.mcap")
    assert digest(recording) == before and not source.unsaved
    old, new = read_trial(recording), read_trial(out)
    assert (old.frames.labels == 1).sum() == N - 37 and (new.frames.labels == 1).sum() == N - 30
    assert np.array_equal(old.frames.probabilities, new.frames.probabilities)
    assert new.label_changes[-2] == (frame_time(30), "US", "correction")
    a, b = open_recording(recording), open_recording(out)
    for topic, info in a.topics.items():  # every original message is in the copy
        expected = info.count + (1 if topic == "/labels" else 0) + (1 if topic == "/events" else 0)
        assert b.topics[topic].count == expected
    assert b.metadata["corrections"]["source"] == recording.name
    assert b.metadata["session"]["subject"] == "S05"
    markers = [m.data for m in b.messages(["/events"]) if m.data["kind"] == "marker"]
    assert markers[0]["message"] == "stairs start here" and markers[0]["time_ns"] == frame_time(30)
    assert source.save_corrections() == recording.with_name("S05_indoor_t03_corrected2.mcap")
    with pytest.raises(Exception, match="new file"):
        write_corrected(recording, recording, [], [])


async def test_replay_in_the_live_screen(recording):
    before = digest(recording)
    # Playback on a clock that stands still: where it is, is what the keys make it.
    source = ReplaySource(recording, clock=FakeClock())
    app = WalkcapApp(Config(), session=source, ask_subject=False, start_status="loading…")
    async with app.run_test(size=(120, 40)) as pilot:
        await wait_for_app(pilot, lambda: app.ready, 60.0)
        live = app.screen
        assert isinstance(live, LiveScreen) and app.subject.subject == "S05"
        await pilot.press("p")
        assert not source.playing
        paused_at = source.position()[0]
        await pilot.press("right")  # + 5 s: past the end of this 4 s file, so the end
        assert source.position()[0] == source.duration_s > paused_at
        await pilot.press("left")  # - 5 s: the start
        pos = source.position()[0]
        assert pos == 0.0
        keys = dict(live.key_help())
        assert "w" in keys and "p" in keys and "r" not in keys and "s" not in keys
        await pilot.press("r")  # no recording in a replay
        assert not source.recording
        source.seek(2.0 - pos)
        await pilot.press("2")
        assert source.corrections[-1].mode == "US" and source.corrections[-1].time_ns == frame_time(
            30
        )
        await pilot.press("q")  # unsaved corrections: asks
        assert isinstance(app.screen, QuitDialog)
        await pilot.press("n")
        await pilot.press("w")
        await wait_for_app(
            pilot, lambda: source.saved_path is not None and not source.unsaved, 60.0
        )  # a bound, not a measure
        assert source.saved_path.exists()
        await pilot.press("q")
        await wait_for_app(pilot, lambda: not app.is_running, 60.0)
    assert digest(recording) == before
    assert (read_trial(source.saved_path).frames.labels == 1).sum() == N - 30


def test_replay_screen_snapshot(recording, snap_compare):
    source = ReplaySource(recording, play=False)

    async def at_stairs(pilot):
        # Generous bounds: a loaded CI machine may take seconds to load and redraw.
        for _ in range(1500):
            if pilot.app.ready:
                break
            await pilot.pause(0.02)
        source.seek(2.2)
        for _ in range(600):  # the image and the profile redraw at most 10 times a second
            await pilot.pause(0.05)
            if pilot.app.screen.settled() and pilot.app.screen._snapshot.latest.index == 33:
                break
        assert pilot.app.screen._snapshot.latest.index == 33, "the replay did not reach frame 33"
        await pilot.pause()

    app = WalkcapApp(Config(), session=source, ask_subject=False, start_status="loading…")
    assert snap_compare(app, terminal_size=(120, 40), run_before=at_stairs)


@pytest.mark.parametrize("width", [120, 80])
async def test_each_replay_correction_shows_at_once_and_notices_fit(recording, width):
    from tui.widgets.decision import DecisionDisplay
    from tui.widgets.notices import NoticeLine
    from tui.widgets.timeline import TimelineStrips

    source = ReplaySource(recording, clock=FakeClock(), play=False)
    app = WalkcapApp(Config(), session=source, ask_subject=False, start_status="loading…")
    async with app.run_test(size=(width, 40)) as pilot:
        await wait_for_app(pilot, lambda: app.ready, 60.0)
        live = app.screen
        source.seek(2.03)  # between frames 30 and 31, paused: nothing moves on its own
        live.refresh_view()
        strips, notices = live.query_one(TimelineStrips), live.query_one(NoticeLine)
        assert strips._entries[-1].index == 30 and strips._entries[-1].label == "LG"
        await pilot.press("2")
        # the frame on screen is relabelled: the true strip and the decision panel say so
        assert strips._entries[-1].label == "US"
        assert live.query_one(DecisionDisplay)._content[2] == "US"
        await pilot.pause()
        shown = notices.render().plain
        assert "US" in shown and "from 2.0 s" in shown and "1 " in shown and "…" not in shown
        assert len(shown) <= width
        await pilot.press("u")
        await pilot.pause()
        assert strips._entries[-1].label == "LG" and "taken back" in notices.render().plain
        await pilot.press("2")
        await pilot.press("w")
        await wait_for_app(
            pilot, lambda: source.saved_path is not None and not source.unsaved, 60.0
        )  # a bound, not a measure
        await pilot.pause()
        shown = notices.render().plain
        assert source.saved_path.name in shown and "…" not in shown, shown
        assert shown.rstrip().endswith("unchanged)") and len(shown) <= width


def test_replay_holds_the_images_around_the_cursor_only(tmp_path):
    """A finished file's images, profiles and terrain features are read around the cursor
    as it moves, the same ones a whole read gives; what is held does not grow with the
    recording."""
    import dataclasses

    from tests.recording_fixtures import imu_sample

    path = tmp_path / "S05_indoor_t04.mcap"
    meta = {"devices": {"camera_fps": "15.0"}}
    rec = Recorder(path, metadata=meta, chunk_interval_s=0.5, queue_size=100_000)
    rec.start()
    n = 15 * 12  # 12 s
    for i in range(n):
        t = frame_time(i)
        image = np.zeros((100, 100), np.uint8)
        image[: 1 + i % 97, :] = 1  # each frame's image its own
        cloud = np.column_stack([np.full(20, 1.0), np.zeros(20), np.full(20, 0.01 * i)])
        rec.write_processed(i, t, t + 1_000_000, cloud, image, np.array([1.0, 0, 0, 0]), "")
        rec.write_inference(i, t, t + 2_000_000, np.full(5, 0.2), {})
        rec.write_features(i, t, {"kind": "level", "slope_deg": 0.1 * i, "segments": [[0, 1]]})
        for k in range(3):  # sensor data: its times close a chunk each 0.5 s
            at = t + k * 20_000_000
            sample = dataclasses.replace(imu_sample(3 * i + k), time_ns=at, host_time_ns=at)
            rec.write_imu(sample)
    rec.close()
    clock = FakeClock()
    source = ReplaySource(path, clock=clock, play=False)
    source.start()
    held = []
    for second in (0.0, 5.0, 11.0, 2.0):
        source.seek(second - source.position()[0])
        snap = source.snapshot()
        i = snap.latest.index
        assert i == round(second * 15)
        assert snap.latest.image.sum() == 100 * (1 + i % 97)
        assert float(snap.latest.profile[0, 1]) == pytest.approx(0.01 * i, abs=2e-3)
        assert snap.latest.features == {"kind": "level", "slope_deg": pytest.approx(0.1 * i)}
        held.append((len(source.frames.images), len(source.frames.features)))
    assert 0 < min(min(h) for h in held) and max(max(h) for h in held) < n / 2
    # what the screen keeps of every frame: its times and scores, its modes as bytes
    per_frame = sum(
        a.nbytes for a in vars(source.frames).values() if isinstance(a, np.ndarray)
    ) / len(source.frames.index)
    assert per_frame <= 6 * 8 + 5 * 4 + 5
