"""The live session on mock devices, end to end: devices -> pipeline -> recording -> replay.

A stand-in classifier keeps these tests independent of the bundled weights; the devices,
preprocessing, fusion and recorder are the real ones.
"""

import os
import threading
import time

import numpy as np
import pytest

from capture.config import Config
from capture.corpus.replay import replay
from capture.corpus.trials import read_trial
from capture.errors import CaptureError, ConfigError
from capture.live.session import INTAKE_THREADS, Session
from capture.live.trials import SubjectInfo
from capture.recording import topics as T
from capture.recording.reader import open_recording
from devices.frames import MODES
from devices.scheduling import realtime_priority
from tests.capture.live.sessions import StandInClassifier


def config(tmp_path, fps=15.0) -> Config:
    c = Config()
    c.session.recordings = str(tmp_path / "recordings")
    c.camera.fps = fps
    return c


_INTAKE: dict = {}  # how the recorded trial's raw-data threads ran: (said, {name: priority})


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One 4-second mock trial, recorded with simulator labels."""
    tmp = tmp_path_factory.mktemp("session")
    session = Session(config(tmp), classifier=StandInClassifier(), auto_label=True)
    session.start()
    try:
        path = session.start_recording(SubjectInfo(subject="S07", condition="indoor", trial=3))
        time.sleep(0.5)
        session.add_marker("subject paused")
        session.set_label("US")
        session.undo_label()
        time.sleep(3.5)
        snap = session.snapshot()
        pipeline = next(t for t in session._threads if t.name == "walkcap-pipeline")
        if session.pipeline_priority.startswith("SCHED_FIFO"):  # as it says, while it runs
            assert os.sched_getscheduler(pipeline.native_id) == os.SCHED_FIFO
        # the threads carrying raw data in, and the writer: one step above the pipeline
        raw = [t for t in threading.enumerate() if t.name in INTAKE_THREADS + ("walkcap-recorder",)]
        intake = {t.name: os.sched_getparam(t.native_id).sched_priority for t in raw}
    finally:
        stats = session.stop()
    _INTAKE["seen"] = (session.intake_scheduling, intake)
    return path, stats, snap, session.pipeline_priority


@pytest.mark.realtime
def test_recording_is_named_from_the_session_and_complete(recorded):
    path, stats, _, priority = recorded
    assert path.name.startswith("S07_indoor_t03_") and path.suffix == ".mcap"
    assert stats.state == "stopped" and stats.dropped == 0
    rec = open_recording(path)
    for topic in (
        "/camera/depth",
        "/camera/cloud",
        "/camera/binary_image",
        "/tf",
        "/imu",
        "/labels",
        "/events",
        "/inference/cnn",
        "/inference/fused",
        "/sim/truth",
    ):
        assert topic in rec.topics, topic
    assert rec.metadata["session"]["subject"] == "S07"
    assert rec.metadata["software"]["model_hash"] == "stand-in"
    assert rec.metadata["software"]["pipeline_priority"] == priority
    assert "walkcap.toml" in rec.attachments


@pytest.mark.realtime
def test_raw_data_threads_and_the_writer_run_above_the_pipeline(recorded):
    path = recorded[0]
    said, priorities = _INTAKE["seen"]
    assert open_recording(path).metadata["software"]["intake_priority"] == said
    if not said.startswith("SCHED_FIFO"):
        pytest.skip("real-time priority not permitted here")
    assert said == "SCHED_FIFO 11"  # the pipeline's 10, plus one
    assert {"walkcap-camera", "walkcap-imu", "walkcap-recorder"} <= set(priorities)
    assert set(priorities.values()) == {11}


@pytest.mark.realtime
def test_rates_match_the_configuration(recorded):
    path, _, snap, _ = recorded
    rec = open_recording(path)
    # Frame k is at k / 15 s of the camera's time line (a loaded machine may skip frames:
    # their indices are missing, the others keep their times).
    depth = [(m.sequence, m.publish_time_ns) for m in rec.messages(["/camera/depth"])]
    starts = {t - int(round(k * (1.0 / 15.0) * 1e9)) for k, t in depth}
    assert len(depth) > 1 and len(starts) == 1
    # The IMU at 100 Hz: 100 ticks of its 10 kHz clock per packet, none lost unseen.
    imu = [m.data for m in rec.messages(["/imu"])]
    ticks = np.diff([s["sample_time_fine"] for s in imu]) % 2**32
    packets = np.diff([s["packet_counter"] for s in imu]) % 2**16
    assert len(imu) > 1 and (packets >= 1).all()
    np.testing.assert_array_equal(ticks, packets * (10_000 // Config().imu.rate_hz))
    assert snap.camera.state == "ok" and snap.imu.state == "ok"


@pytest.mark.realtime
def test_labels_markers_and_undo_are_recorded(recorded):
    path, _, _, _ = recorded
    trial = read_trial(path)
    sources = [c[2] for c in trial.label_changes]
    assert "operator" in sources and any(s.startswith("undo") for s in sources)
    assert "simulator" in sources or "start" in sources
    events = [m.data for m in open_recording(path).messages(["/events"])]
    assert any(e["kind"] == "marker" and e["message"] == "subject paused" for e in events)


@pytest.mark.realtime
def test_fused_decisions_refer_to_earlier_frames(recorded):
    path, _, _, _ = recorded
    fused = [m.data for m in open_recording(path).messages(["/inference/fused"])]
    cnn = {
        m.data["frame_index"]: m.sequence for m in open_recording(path).messages(["/inference/cnn"])
    }
    assert fused
    first = min(cnn)  # frames before the recording started are decided in it too
    for f in fused:
        assert f["frame_index"] in cnn or f["frame_index"] < first  # camera frame indices
        assert f["frame_index"] < max(cnn)
        assert f["decision"] in MODES


@pytest.mark.realtime
def test_imu_is_aligned_with_frames_on_the_session_clock(recorded):
    _, _, snap, _ = recorded
    # the emulator knows when it really sampled: the mapped times are close to that
    assert snap.sync and snap.sync["p50_ms"] < 1.0


@pytest.mark.realtime
def test_replay_reproduces_the_trial_into_a_new_file(recorded, tmp_path):
    path, _, _, _ = recorded
    before = path.read_bytes()
    report = replay(path, Config(), output=tmp_path / "again.mcap", classifier=StandInClassifier())
    assert path.read_bytes() == before  # the original is never modified
    a, b = read_trial(path), read_trial(report.output)

    def stale(file) -> dict[int, int]:
        return {
            m.data["frame_index"]: m.data["time_ns"]
            for m in open_recording(file).messages(["/camera/preprocess"])
            if m.data.get("flag") == "stale_orientation"
        }

    # The live run may leave a frame undecided because its IMU sample came too late (a
    # busy host); replay, with every sample there, decides it. Replay may leave the last
    # frames undecided when the file's IMU samples end before them (the ones the live run
    # used arrived after the recording stopped). Every other frame is the same.
    live, again = stale(path), stale(report.output)
    last_imu = max(m.publish_time_ns for m in open_recording(path).messages(["/imu"]))
    assert all(t > last_imu for i, t in again.items() if i not in live)
    either = set(live) | set(again)
    assert set(a.frames.index) | either == set(b.frames.index) | either
    assert not set(a.frames.index) & set(live) and not set(b.frames.index) & set(again)
    assert len(b.frames.index) + len(again) == report.frames
    assert [c[:2] for c in a.label_changes] == [c[:2] for c in b.label_changes]
    assert report.speedup > 0
    software = open_recording(report.output).metadata["software"]
    assert software["replay_of"] == path.name and software["model_hash"] == "stand-in"
    assert software["fusion_method"] == Config().fusion.method  # what decided the replay
    depth_a = [m.data for m in open_recording(path).messages(["/camera/depth"])]
    depth_b = [m.data for m in open_recording(report.output).messages(["/camera/depth"])]
    assert len(depth_a) == len(depth_b)
    for x, y in zip(depth_a, depth_b):
        np.testing.assert_array_equal(x, y)  # the recorded millimetres, not a re-encoding


@pytest.mark.realtime
def test_a_fast_replay_stopped_by_an_error_ends_its_reader(recorded, tmp_path, monkeypatch):
    """The reader process is still sending when this side fails: it ends at once, and
    what was recorded up to there stays readable."""
    import capture.corpus.replay as R

    readers = []

    class Kept(R._ReaderProcess):
        def __init__(self, *args):
            super().__init__(*args)
            readers.append(self)

    monkeypatch.setattr(R, "_ReaderProcess", Kept)

    class Failing(StandInClassifier):
        def predict(self, image):
            if len(calls) == 40:  # in the third block of 16
                raise RuntimeError("classifier broke")
            calls.append(1)
            return super().predict(image)

    calls: list = []
    path, _, _, _ = recorded
    started = time.monotonic()
    with pytest.raises(RuntimeError, match="classifier broke"):
        replay(path, Config(), output=tmp_path / "cut.mcap", classifier=Failing())
    assert time.monotonic() - started < 10
    (reader,) = readers
    assert not reader._child.running() and not reader._receiver.is_alive()
    assert open_recording(tmp_path / "cut.mcap").topics["/camera/depth"].count >= 1


@pytest.mark.realtime
def test_replay_refuses_to_overwrite_its_source(recorded):
    path, _, _, _ = recorded
    with pytest.raises(CaptureError, match="new file"):
        replay(path, Config(), output=path, classifier=StandInClassifier())


def test_realtime_priority_goes_to_the_given_thread_alone_where_permitted(monkeypatch):
    waiting = threading.Event()
    thread = threading.Thread(target=waiting.wait)
    thread.start()
    try:
        assert realtime_priority(thread.native_id, 0) == "normal"
        said = realtime_priority(thread.native_id, 10)
        if os.geteuid() == 0:  # root may; CI and the bench run as root
            assert said == "SCHED_FIFO 10"
        expected = os.SCHED_FIFO if said.startswith("SCHED_FIFO") else os.SCHED_OTHER
        assert os.sched_getscheduler(thread.native_id) == expected
        assert os.sched_getscheduler(threading.get_native_id()) == os.SCHED_OTHER

        def refused(*args):
            raise PermissionError(1, "Operation not permitted")

        monkeypatch.setattr(os, "sched_setscheduler", refused)
        assert (
            realtime_priority(thread.native_id, 10) == "normal (real-time priority not permitted)"
        )
    finally:
        waiting.set()
        thread.join()


def test_a_priority_out_of_range_is_refused_before_any_device_opens():
    cfg = Config()
    cfg.session.realtime_priority = 120
    session = Session(cfg, classifier=StandInClassifier())
    with pytest.raises(ConfigError, match="realtime_priority"):
        session.start()
    assert session._camera is None and not session._threads


def test_unknown_label_is_refused():
    session = Session(Config(), classifier=StandInClassifier())
    with pytest.raises(CaptureError, match="unknown mode"):
        session.set_label("XX")


@pytest.mark.realtime
def test_fast_replay_in_two_processes_matches_a_paced_one(recorded, tmp_path):
    """The reader process and batched classification change nothing but the speed."""
    path, _, _, _ = recorded
    fast = replay(path, Config(), output=tmp_path / "fast.mcap", classifier=StandInClassifier())
    paced = replay(
        path, Config(), output=tmp_path / "paced.mcap", speed=50.0, classifier=StandInClassifier()
    )
    a, b = read_trial(fast.output), read_trial(paced.output)
    assert fast.frames == paced.frames > 30
    for key in ("index", "probabilities", "cnn_decision", "decision", "voted"):
        np.testing.assert_array_equal(getattr(a.frames, key), getattr(b.frames, key))

    def features(p):  # measured from the terrain the reader process prepared, or this one
        return [(m.sequence, m.data) for m in open_recording(p).messages([T.FEATURES])]

    assert len(features(fast.output)) > 30
    assert features(fast.output) == features(paced.output)
    assert sum(d["kind"] != "unknown" for _, d in features(fast.output)) > 10


def test_fast_replay_classifies_in_batches_of_a_fixed_size_however_frames_come():
    """The CNN's float results depend on a batch's size: fixed batches from the first
    frame on make every fast replay of a file the same."""
    import capture.corpus.replay as R

    blocks = [[0], [1, 2, 3], [4], [5, 6, 7, 8, 9], [10]]
    assert list(R._fixed_batches(iter(blocks), 4)) == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10]]
    assert list(R._fixed_batches(iter([]), 4)) == []


def test_the_reader_process_hands_over_what_has_come_without_waiting_for_a_full_batch():
    """Frames already waiting join the first frame's block (up to the size), and an
    error still gives the frames before it first."""
    import queue

    import capture.corpus.replay as R

    reader = R._ReaderProcess.__new__(R._ReaderProcess)  # its queue alone, no process
    reader._received = queue.Queue()
    reader._received.put(("frame", 0))
    batches = reader.batches(4)
    assert next(batches) == [0]
    for k in range(1, 7):
        reader._received.put(("frame", k))
    reader._received.put(("error", "the recording is damaged"))
    assert next(batches) == [1, 2, 3, 4]
    assert next(batches) == [5, 6]
    with pytest.raises(CaptureError, match="damaged"):
        next(batches)


@pytest.mark.realtime
def test_fast_replay_prepares_frames_itself_until_its_reader_process_is_ready(recorded):
    """The steps done here while the reader starts, then the reader's from the next on:
    each step once, in order, the same as the reader would have made them."""
    import capture.corpus.replay as R

    path, _, _, _ = recorded
    config = Config()
    params, mounting = config.preprocess, config.mounting

    class Reader:  # stands in for the reader process
        ready = threading.Event()
        skip = None
        times = None

        def claim_start(self, who):
            return who == "host"  # this side comes to the frames first

        def start_at(self, skip):
            self.skip = skip

        def batches(self, size):
            for step in R.replay_steps(path, params, mounting, skip=self.skip):
                yield [step]

    reader = Reader()
    steps = []
    for block in R._head_start(path, params, mounting, reader):
        steps += block
        if len(steps) == 3:
            reader.ready.set()  # the reader process says it is ready
    every = list(R.replay_steps(path, params, mounting))
    assert reader.skip == 3
    assert [s.frame.index if s.frame else None for s in steps] == [
        s.frame.index if s.frame else None for s in every
    ]
    assert len(every) > 30 and every[-1].frame is None
    assert [len(s.imu) for s in steps] == [len(s.imu) for s in every]
    skipped = R.replay_steps(path, params, mounting, skip=5)
    first = next(skipped)
    assert first.frame.index == every[5].frame.index
    assert np.array_equal(first.orientation, every[5].orientation)


def test_a_reader_process_ready_first_gives_every_step():
    """Ready before this side comes to the frames (this side loads the model meanwhile),
    the reader process starts at the first step and this side prepares none itself."""
    import queue
    import types

    import capture.corpus.replay as R

    reader = R._ReaderProcess.__new__(R._ReaderProcess)  # no process: its start and queue
    reader._start_lock, reader._starter, reader.times = threading.Lock(), None, None
    sent: list = []
    reader._child = types.SimpleNamespace(conn=types.SimpleNamespace(send=sent.append))
    reader._received = queue.Queue()
    assert reader.claim_start("child")  # at its ready message
    reader.start_at(0)
    for k in range(3):
        reader._received.put(("frame", k))
    reader._received.put(("end",))
    blocks = list(R._head_start("no such file", None, None, reader))
    assert sent == [(0, None)] and blocks == [[0, 1, 2]]
    assert not reader.claim_start("host")


def test_switches_are_counted_over_the_last_minute():
    from capture.live.timeline import SwitchCounter

    counter = SwitchCounter(60.0)
    s = 1_000_000_000
    for t, final in [(0, 0), (1, 0), (2, 1), (3, None), (4, 1), (5, 0), (50, 2)]:
        counter.add(t * s, final)
    assert counter.count() == 3  # 0 -> 1 at 2 s, 1 -> 0 at 5 s, 0 -> 2 at 50 s
    counter.add(66 * s, 2)
    assert counter.count() == 1  # those at 2 s and 5 s are more than a minute old


@pytest.mark.realtime
def test_the_snapshot_carries_switches_and_the_walkers_mode_to_key(recorded):
    path, _, snap, _ = recorded
    assert snap.walker_mode in MODES and isinstance(snap.switches_last_minute, int)
    # auto-labels key the walker's locomotion mode, as an operator keys it
    walker = {
        m.data["time_ns"]: m.data["locomotion_mode"]
        for m in open_recording(path).messages(["/sim/truth"])
    }
    keyed = [c for c in read_trial(path).label_changes if c[2] == "simulator"]
    assert keyed and all(walker[t] == mode for t, mode, _ in keyed if t in walker)


def test_a_host_stall_is_one_event_that_names_the_host(tmp_path, monkeypatch):
    import types

    import capture.live.session as session_module

    session = Session(config(tmp_path), classifier=StandInClassifier())
    quiet = types.SimpleNamespace(poll_events=lambda: [])
    session._camera = session._imu = quiet
    clock = {"t": 10**12, "ticks": 0}

    def now():  # 0.2 s a tick, and once 5 s: the host stood still
        clock["ticks"] += 1
        clock["t"] += 5_000_000_000 if clock["ticks"] == 3 else 200_000_000
        if clock["ticks"] >= 6:
            session._stop.set()
        return clock["t"]

    monkeypatch.setattr(session_module, "now_ns", now)
    worker = threading.Thread(target=session._monitor_loop, daemon=True)
    worker.start()
    worker.join(60.0)  # a bound: it ends once the clock above stopped it
    session._stop.set()
    worker.join(5.0)
    stalls = [e for e in session._events if e.kind == "stall"]
    assert [(e.device, round(e.details["gap_s"], 1)) for e in stalls] == [("host", 5.0)]
    assert "the computer stalled for 5.00 s" in stalls[0].message


@pytest.mark.realtime
def test_a_mock_trial_records_the_walks_gait_and_the_detectors(recorded):
    from capture.corpus import export
    from capture.recording.gait import read_gait
    from inference.gait import match_events

    path, _, snap, _ = recorded
    rec = open_recording(path)
    assert T.GAIT in rec.topics and T.SIM_GAIT in rec.topics
    truth, found = read_gait(rec, source="simulator"), read_gait(rec, source="imu")
    contacts = truth.heel_contacts()
    assert len(contacts) >= 2 and set(contacts.mode) <= set(MODES)
    assert set(found.mode) == {""}  # the detector does not know the terrain
    # the walk's heel contacts are the detector's, within 60 ms (one at the file's start
    # may have been detected before the recording began)
    pairs = match_events(contacts.time_ns, found.heel_contacts().time_ns, 60_000_000)
    assert len(pairs) >= len(contacts) - 1 and len(pairs) >= 1
    assert all("gait" not in m.data for m in rec.messages([T.TRUTH]))  # on its own topic
    assert snap.steps is not None and snap.steps >= 2
    assert snap.cadence_spm is not None and 80 < snap.cadence_spm < 130
    gait = export.tables(path)["gait"]
    assert set(gait["source"]) == {"imu", "simulator"}
    assert list(gait.columns[-6:]) == [
        "time_ns",
        "unix_time_ns",
        "time_s",
        "event",
        "source",
        "mode",
    ]
    assert gait["time_ns"].is_monotonic_increasing and (gait["time_s"] >= 0).all()


@pytest.mark.realtime
def test_replay_keeps_the_walks_gait_and_detects_the_same_steps(recorded, tmp_path):
    from capture.recording.gait import read_gait

    path, _, _, _ = recorded
    report = replay(path, Config(), output=tmp_path / "gait.mcap", classifier=StandInClassifier())
    assert read_gait(report.output, "simulator").events() == read_gait(path, "simulator").events()
    live = read_gait(path, "imu").heel_contacts().time_ns
    again = read_gait(report.output, "imu").heel_contacts().time_ns
    # the same samples, the same detector: the same heel contacts, but for one the live
    # detector placed from samples before the recording began
    common = [t for t in again if np.min(np.abs(live - t)) <= 1_000]
    assert len(again) >= 1 and len(common) >= len(again) - 1


def _tf_against_the_walk(path) -> dict:
    """Per frame index: the optical axis's elevation from /tf, and from the simulator's
    camera pose (camera -> world, z up), degrees."""
    rec = open_recording(path)
    tf = {m.sequence: m.data for m in rec.messages([T.TF])}
    pose = {m.data["frame_index"]: m.data["camera_pose"] for m in rec.messages([T.TRUTH])}
    out = {}
    for k in sorted(set(tf) & set(pose)):
        w, x, y, z = tf[k]
        sines = np.clip([1 - 2 * (x * x + y * y), np.asarray(pose[k])[2, 2]], -1.0, 1.0)
        out[k] = np.degrees(np.arcsin(sines))
    return out


def _off_the_walk(elevations: dict) -> float:
    """The median of |elevation from /tf - the walk's|, degrees."""
    return float(np.median([abs(a - b) for a, b in elevations.values()]))


@pytest.mark.realtime
def test_tf_is_the_cameras_orientation_live_and_in_replay(recorded, tmp_path):
    """/tf's child frame is the camera: its optical axis rises and falls as the walk's
    camera does (the IMU's orientation there would be some 110 degrees off), and the
    frame table's camera elevation, the gait cue of fusion, reads it."""
    path = recorded[0]
    live = _tf_against_the_walk(path)
    assert len(live) > 20 and _off_the_walk(live) < 5.0
    frames = read_trial(path).frames
    table = dict(zip(frames.index.tolist(), frames.camera_elevation_deg.tolist()))
    shared = sorted(set(table) & set(live))
    assert len(shared) > 20
    np.testing.assert_allclose([table[k] for k in shared], [live[k][0] for k in shared])
    out = replay(path, config(tmp_path), output=tmp_path / "r.mcap", speed=None).output
    assert _off_the_walk(_tf_against_the_walk(out)) < 5.0
