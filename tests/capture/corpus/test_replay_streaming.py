"""Replay reads a recording in one pass: IMU samples handed out in sample-time order (the
order a sort of every sample in memory gives), and what it does not change copied as
recorded."""

import collections
import dataclasses
import random

import numpy as np
import orjson
import pytest

import capture.corpus.replay as R
from capture.config import Config
from capture.recording import topics as T
from capture.recording.encode import encode_depth, encode_imu, encode_truth
from capture.recording.reader import FrameAssembler, imu_sample, open_recording
from capture.recording.writer import Recorder
from tests.capture.live.sessions import StandInClassifier
from tests.recording_fixtures import ATTACHMENTS, METADATA, frame_at, frame_time, write_recording

MS = 1_000_000


def test_samples_come_in_the_order_a_sort_in_memory_gives():
    """Samples written out of order within the horizon, some at the same time: each
    frame gets the ones up to its time, in the order of a stable sort by time."""
    rng = random.Random(4)
    times = [k * 10 * MS for k in range(400)]
    times[61] = times[60]  # the same time: the file's order decides
    written = sorted(range(400), key=lambda k: times[k] + rng.uniform(0, 500) * MS)
    order = R.SampleOrder()
    frames = [k * 22 * MS for k in range(180)]
    got, waiting = [], collections.deque(frames)
    for k in written:
        order.read_to(times[k] + 600 * MS)  # logged up to 0.6 s after its time
        order.add(times[k], k)
        while waiting and order.ready(waiting[0] + R.IMU_LOOKAHEAD_NS):
            got.append(order.take(waiting.popleft() + R.IMU_LOOKAHEAD_NS))
    order.end()
    got += [order.take(t + R.IMU_LOOKAHEAD_NS) for t in waiting]
    got.append(order.take())
    by_time = sorted(written, key=lambda k: times[k])  # stable: file order among equals
    assert [k for taken in got for k in taken] == by_time
    for t, taken in zip(frames, got):
        assert all(times[k] <= t + R.IMU_LOOKAHEAD_NS for k in taken)
    assert written != by_time and by_time.index(61) == by_time.index(60) + 1


def test_a_sample_held_past_the_horizon_is_caught_and_known_times_wait_for_it():
    order = R.SampleOrder()
    for k in range(300):
        order.read_to(k * 10 * MS)
        order.add(k * 10 * MS, k)
    assert order.ready(100 * MS) and order.take(100 * MS) == list(range(11))
    with pytest.raises(R.ImuOrderError):
        order.add(50 * MS, "late")

    times = np.sort(np.array([k * 10 * MS for k in range(300)] + [50 * MS]))
    order = R.SampleOrder(times)
    for k in range(300):
        order.read_to(k * 10 * MS)
        order.add(k * 10 * MS, k)
    assert not order.ready(100 * MS)  # one sample up to there is not read yet
    order.add(50 * MS, "late")
    assert order.ready(100 * MS)
    assert order.take(100 * MS) == [0, 1, 2, 3, 4, 5, "late", 6, 7, 8, 9, 10]


def _late_sample_recording(path, late_by_s: float = 3.0):
    """Frames at 45 fps for 4 s with the IMU at 100 Hz, one sample written `late_by_s`
    after its time (a host that delivered it late)."""
    from tests.recording_fixtures import imu_sample as fixture_sample

    late = 37
    with Recorder(path, metadata=METADATA, attachments=ATTACHMENTS, queue_size=100_000) as rec:
        k_imu = 0
        for i in range(180):
            t = frame_time(i)
            while frame_time(0) + k_imu * 10 * MS <= t:
                if k_imu != late:
                    rec.write_imu(fixture_sample(k_imu))
                k_imu += 1
            if t >= fixture_sample(late).time_ns + int(late_by_s * 1e9):
                rec.write_imu(fixture_sample(late))
                late = -1
            frame = frame_at(i)
            rec.write_frame(frame)
            rec.write_truth(i, t, frame.truth)
    return path


def _messages(path) -> dict:
    out = collections.defaultdict(list)
    for _, channel, m in open_recording(path)._raw(None, None, None):
        out[channel.topic].append((m.log_time, m.publish_time, m.sequence, bytes(m.data)))
    return out


def _in_this_process(source, output):
    """A replay of `source` into `output` in this process alone, with the stand-in model."""
    return R.replay(
        source, Config(), output=output, classifier=StandInClassifier(), reader_process=False
    )


def _passes(monkeypatch) -> list:
    """The replay's passes over the file as they start: True for one that read every
    sample's time first (after ImuOrderError)."""
    passes = []
    steps = R.replay_steps

    def counted(*args, **kwargs):
        passes.append(kwargs.get("times") is not None)
        return steps(*args, **kwargs)

    monkeypatch.setattr(R, "replay_steps", counted)
    return passes


def test_a_sample_held_late_gives_the_replay_that_reads_every_sample_first(tmp_path, monkeypatch):
    source = _late_sample_recording(tmp_path / "late.mcap")
    in_file = [imu_sample(m.data).time_ns for m in open_recording(source).messages([T.IMU])]
    assert in_file != sorted(in_file)

    def replayed(name: str):
        return _in_this_process(source, tmp_path / name)

    passes = _passes(monkeypatch)
    caught = replayed("a.mcap")
    assert passes == [False, True]  # the pass within the horizon failed; the one with times
    monkeypatch.setattr(R.SampleOrder, "HORIZON_NS", 10**15)  # every sample read first
    reference = replayed("b.mcap")
    assert caught.frames == reference.frames == 180
    a, b = _messages(caught.output), _messages(reference.output)
    assert a == b and len(a[T.TF]) == 180
    written = [imu_sample(orjson.loads(d)).time_ns for _, _, _, d in a[T.IMU]]
    assert written == sorted(in_file)


def _label_ahead(source, target, ahead_s: float):
    """`source` copied with an operator label logged `ahead_s` after its first IMU sample
    placed right after that sample: where a label that jumped the writer's queue lies."""
    from capture.recording.copy import RecordingCopy, new_recording
    from capture.recording.messages import iter_raw

    rec = open_recording(source)
    with new_recording(target) as out:
        copy = RecordingCopy(out)
        copy.start()
        for name, values in rec.metadata_records:
            copy.metadata(name, T.encode_metadata(values))
        for name, data in rec.attachments.items():
            copy.attachment(0, 0, name, "application/octet-stream", data)
        placed = False
        for schema, channel, message in iter_raw(source, rec.complete, None):
            copy.channel(channel, schema)
            copy.message(message)
            if channel.topic == T.IMU and not placed:
                at = message.log_time + int(ahead_s * 1e9)
                copy.add(T.LABELS, T.label_json(at, "US", "operator"))
                placed = True
        copy.finish()
    return target


def test_a_label_ahead_of_the_samples_in_the_file_does_not_stop_the_pass(tmp_path, monkeypatch):
    """Labels and events jump the writer's queue (a backed-up queue puts a label seconds
    ahead of samples logged before it): the pass goes by the samples' and frames' log
    times, and needs no second one."""
    write_recording(tmp_path / "plain.mcap", seconds=4.0)
    source = _label_ahead(tmp_path / "plain.mcap", tmp_path / "ahead.mcap", 3.0)
    topics = [m.topic for m, _ in open_recording(source).stored([T.IMU, T.LABELS])]
    assert topics.index(T.LABELS) < 5  # right after the first sample
    passes = _passes(monkeypatch)
    report = _in_this_process(source, tmp_path / "again.mcap")
    assert passes == [False] and report.frames == open_recording(source).topics[T.DEPTH].count


def test_replay_copies_what_it_does_not_change_as_recorded(tmp_path):
    """Depth, confidence, truth, IMU samples, labels and events: the messages' bytes as
    the recording holds them, which are what encoding the decoded data again gives."""
    source = tmp_path / "S07_indoor_t03.mcap"
    write_recording(source, seconds=2.0)
    report = R.replay(
        source, Config(), output=tmp_path / "again.mcap", classifier=StandInClassifier()
    )
    a, b = _messages(source), _messages(report.output)
    for topic in (T.DEPTH, T.CONFIDENCE, T.TRUTH, T.IMU, T.LABELS):
        assert a[topic] == b[topic] and len(a[topic]) > 1, topic
    # an operator's marker is written ahead of the queue, as live: the same messages
    assert sorted(a[T.EVENTS]) == sorted(b[T.EVENTS]) and len(a[T.EVENTS]) == 2

    rec = open_recording(source)
    frames = FrameAssembler(rec)
    entries = [e for m in rec.messages(frames.topics) for e in frames.add(m)]
    for entry, depth, truth in zip(entries, a[T.DEPTH], a[T.TRUTH], strict=True):
        frame = frames.frame(entry)
        t, log_time = frame.device_time_ns, frame.host_time_ns
        again = encode_depth(frame, t, log_time) + encode_truth(
            frame.index, t, log_time, frame.truth
        )
        assert [bytes(m.data) for m in again] == [
            depth[3],
            a[T.CONFIDENCE][frame.index][3],
            truth[3],
        ]
    for m, stored in zip(rec.messages([T.IMU]), a[T.IMU], strict=True):
        assert encode_imu(imu_sample(m.data))[0].data == stored[3]


def test_the_reader_process_fits_the_profile_as_the_live_pipeline_would(tmp_path, monkeypatch):
    """The reader process fits each frame's profile (inference.features.fit_profile) and the
    host classifies the fit under the fused decision: the same file as the live pipeline's
    way, the whole terrain_features on the host from the profile, gives (the features'
    floats to the last bits: the compiled fit against numpy's, tests/inference)."""
    from capture.live.pipeline import Pipeline

    source = tmp_path / "S07_indoor_t04.mcap"
    write_recording(source, seconds=3.0)
    fast = R.replay(source, Config(), output=tmp_path / "fast.mcap", classifier=StandInClassifier())

    slim = R._slim
    process = Pipeline.process

    def with_profile(frame, pre, kept):
        thin, thin_pre = slim(frame, pre, kept)
        return thin, dataclasses.replace(thin_pre, profile=pre.profile)

    monkeypatch.setattr(R, "_slim", with_profile)
    monkeypatch.setattr(
        Pipeline, "process", lambda self, *a, fit=None, **k: process(self, *a, **k, fit=None)
    )
    live = _in_this_process(source, tmp_path / "live.mcap")
    a, b = _messages(fast.output), _messages(live.output)
    assert a.keys() == b.keys()
    for topic in a.keys() - {T.FEATURES}:
        assert a[topic] == b[topic], topic
    assert len(a[T.FEATURES]) == len(b[T.FEATURES]) == fast.frames > 60
    kinds = collections.Counter()
    for x, y in zip(a[T.FEATURES], b[T.FEATURES]):
        assert x[:3] == y[:3]
        u, v = orjson.loads(x[3]), orjson.loads(y[3])
        assert u.keys() == v.keys()
        for key in u:
            if isinstance(u[key], float) and isinstance(v[key], float):
                assert abs(u[key] - v[key]) <= 1e-6, key
            else:
                assert u[key] == v[key], key
        kinds[u["kind"]] += 1
    assert fast.frames - kinds["unknown"] > 30, kinds  # terrain, measured


def test_the_reader_sends_from_a_thread_in_order_and_stops_when_nobody_listens():
    """The reader process's messages go out in the order made, from a thread of their
    own (the reader goes on while the other side is slow to take them); once the other
    side has gone, a message is refused and the thread ends."""
    from multiprocessing import Pipe

    ours, theirs = Pipe()
    outbox = R._Outbox(ours)
    payloads = [bytes([k]) * (1 + 1000 * k) for k in range(5)]
    assert all(outbox.put(p) for p in payloads)
    assert [theirs.recv_bytes() for _ in payloads] == payloads
    theirs.close()
    big = b"x" * (1 << 20)  # beyond what the socket holds: the send finds nobody
    assert not all(outbox.put(big) for _ in range(100))
    outbox.close()
    assert not outbox._thread.is_alive()
    ours.close()


def test_a_replayed_frame_keeps_the_order_of_a_live_frames_messages():
    from capture.recording.encode import Encoded

    def m(topic):
        return Encoded(topic, 1, 1, b"", 0)

    read = [m(T.DEPTH), m(T.CONFIDENCE), m(T.CLOUD), m(T.TRUTH)]
    host = [m(T.BINARY_IMAGE), m(T.PREPROCESS), m(T.TF)]
    order = [x.topic for x in R._with_processed(read, host)]
    assert order == [T.DEPTH, T.CONFIDENCE, T.CLOUD, T.BINARY_IMAGE, T.PREPROCESS, T.TF, T.TRUTH]
    assert [x.topic for x in R._with_processed(read[:3], host)] == order[:-1]
