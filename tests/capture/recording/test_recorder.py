"""The recorder: every topic decodes with the schema in the file, depth is exact to 0.5 mm,
writes never block, drops are counted and recorded, write errors end in a readable file."""

from __future__ import annotations

import errno
import json
import os
import threading
import time

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_protobuf.decoder import DecoderFactory

from capture.errors import CaptureError
from capture.recording import chunks as chunk_writer
from capture.recording import topics as T
from capture.recording.chunks import TrackedFile
from capture.recording.journal import read_journal
from capture.recording.reader import depth_frames, open_recording
from capture.recording.recover import recover
from capture.recording.writer import Recorder
from devices.frames import CameraGeometry
from devices.simulator.synthetic import synthetic_frame
from tests.recording_fixtures import (
    ATTACHMENTS,
    FPS,
    METADATA,
    T0,
    disk_full_after,
    frame_at,
    frame_time,
    imu_sample,
    label_schedule,
    write_recording,
)


def decode_all(path):
    """Every message of the file, decoded with the schema stored in the file."""
    factory = DecoderFactory()
    out: dict[str, list] = {}
    validators: dict[int, jsonschema.protocols.Validator] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                if schema.id not in validators:
                    validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
                data = json.loads(message.data)  # strict JSON: no NaN
                validators[schema.id].validate(data)
            else:
                assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
                data = factory.decoder_for(channel.message_encoding, schema)(message.data)
            out.setdefault(channel.topic, []).append((message, data))
    return out


def test_every_topic_round_trips_and_decodes_with_the_schema_in_the_file(tmp_path):
    path = tmp_path / "trial.mcap"
    stats = write_recording(path, seconds=2.0).stats()
    assert stats.state == "stopped" and stats.dropped == 0 and stats.errors == 0
    msgs = decode_all(path)
    n = int(2.0 * FPS)
    assert {t: len(v) for t, v in msgs.items()} == {
        T.DEPTH: n,
        T.CONFIDENCE: n,
        T.CLOUD: n,
        T.BINARY_IMAGE: n,
        T.PREPROCESS: n,
        T.TF: n - 1,
        T.IMU: len(msgs[T.IMU]),
        T.CNN: n,
        T.FUSED: n - 2,
        T.FEATURES: n,
        T.TRUTH: n,
        T.LABELS: len(label_schedule(2.0)),
        T.EVENTS: 2,
    }
    assert len(msgs[T.IMU]) == 198  # up to the last frame at 89/45 s, 100 Hz

    message, depth = msgs[T.DEPTH][7]  # times: log = host receive, publish = sample time
    assert (message.sequence, message.log_time, message.publish_time) == (
        7,
        frame_at(7).host_time_ns,
        frame_time(7),
    )
    assert depth.encoding == "16UC1" and depth.step == 2 * depth.width
    assert depth.timestamp.seconds * 10**9 + depth.timestamp.nanos == frame_time(7)

    _, tf = msgs[T.TF][0]
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "camera")
    assert tf.rotation.w == pytest.approx(np.cos(0.1)) and tf.rotation.y == pytest.approx(
        np.sin(0.1)
    )
    _, cloud = msgs[T.CLOUD][3]
    xyz = T.cloud_from_message(cloud)
    expected = np.column_stack(
        [np.linspace(0.0, 1.5, 300), np.zeros(300), np.full(300, -0.55) + 0.003]
    )
    assert xyz.dtype == np.float32 and np.abs(xyz - expected).max() <= T.CLOUD_QUANTUM_M / 2 + 1e-6
    _, image = msgs[T.BINARY_IMAGE][0]
    img = T.image_from_message(image)
    assert image.encoding == "mono8" and set(np.unique(img)) == {0, 255} and img[50:].all()

    imu = [d for _, d in msgs[T.IMU]]
    ref = imu_sample(3)
    assert imu[3]["packet_counter"] == 3 and imu[3]["time_ns"] == ref.time_ns
    assert imu[3]["quaternion"] == pytest.approx(ref.quaternion.tolist())
    assert imu[3]["extra"] == {"temperature": 31.5} and imu[3]["status_word"] == 3
    assert msgs[T.IMU][3][0].log_time == ref.host_time_ns

    labels = sorted((d["time_ns"], d["mode"], d["source"]) for _, d in msgs[T.LABELS])
    assert labels == label_schedule(2.0)
    events = {d["kind"]: d for _, d in msgs[T.EVENTS]}
    assert events["gap"]["details"] == {"missing": 3} and events["marker"]["device"] == "operator"
    fused = [d for _, d in msgs[T.FUSED]]
    assert fused[1]["source_frame_index"] == 3 and fused[1]["frame_index"] == 2
    assert fused[0]["voted"] is None
    features = msgs[T.FEATURES][0][1]
    assert features["tread_m"] is None and features["riser_m"] == 0.17  # NaN becomes null
    pre = [d for _, d in msgs[T.PREPROCESS]]
    assert pre[5]["flag"] == "no orientation" and not pre[5]["oriented"] and pre[4]["oriented"]

    rec = open_recording(path)
    assert rec.complete
    for name, values in METADATA.items():
        assert rec.metadata[name] == values
    assert rec.metadata["camera"]["width"] == 224  # typed metadata
    assert rec.metadata["recording_end"]["messages"] == stats.messages
    assert int(rec.metadata["recording"]["unix_offset_ns"]) > 0
    for name, data in ATTACHMENTS.items():
        assert rec.attachments[name] == data
    assert rec.rays().shape == (171, 224, 3)


def test_depth_rebuilds_within_half_a_millimetre_along_the_ray(tmp_path):
    path = tmp_path / "depth.mcap"
    geometry = CameraGeometry(serial="0005-1234")
    frames = [synthetic_frame(i, frame_time(i), geometry=geometry) for i in range(3)]
    frames[1].confidence[:20, :30] = 0  # invalid pixels: royale gives xyz 0 there
    frames[1].xyz[:20, :30] = 0
    frames[1].confidence[40:50, 40:50] = 17  # a low but valid confidence is kept as is
    with Recorder(path, metadata={}, gray=True) as rec:
        for f in frames:
            rec.write_frame(f)
    rebuilt = list(depth_frames(path))
    assert [f.index for f in rebuilt] == [0, 1, 2]
    rays = geometry.rays()
    for original, back in zip(frames, rebuilt):
        assert back.geometry == geometry
        assert back.device_time_ns == original.device_time_ns
        assert back.host_time_ns == original.host_time_ns
        np.testing.assert_array_equal(back.confidence, original.confidence)
        np.testing.assert_array_equal(back.gray, original.gray)
        valid = original.confidence > 0
        error = back.xyz.astype(np.float64) - original.xyz.astype(np.float64)
        assert np.linalg.norm(error, axis=-1)[valid].max() <= 0.0005 + 1e-6
        across = error - np.einsum("...i,...i->...", error, rays)[..., None] * rays
        assert np.linalg.norm(across, axis=-1).max() < 1e-5  # only along the ray
        assert not back.xyz[~valid].any()
        assert back.truth is None  # truth is recorded by write_truth, not write_frame


def test_range_quantisation_bound_on_random_points():
    rng = np.random.default_rng(3)
    rays = CameraGeometry().rays()
    r = rng.uniform(0.1, 4.0, rays.shape[:2])
    xyz = (rays * r[..., None]).astype(np.float32)
    confidence = np.full(r.shape, 255, np.uint8)
    back = T.xyz_from_range(T.range_mm(xyz, confidence), rays)
    assert np.linalg.norm(back - xyz, axis=-1).max() <= 0.0005 + 1e-6


def _held_writer(monkeypatch, path, queue_size: int):
    """A started recorder whose writer holds its first frame (a disk or CPU that cannot keep
    up) until the returned event is set."""
    real = chunk_writer.encode_depth
    encoding, disk_free = threading.Event(), threading.Event()

    def stuck(*args):
        encoding.set()
        disk_free.wait(10.0)
        return real(*args)

    monkeypatch.setattr(chunk_writer, "encode_depth", stuck)
    rec = Recorder(path, metadata={}, queue_size=queue_size)
    rec.start()
    rec.write_frame(frame_at(0))
    assert encoding.wait(5.0)
    return rec, disk_free


def test_a_full_queue_drops_counts_and_records_but_never_blocks_or_loses_labels(
    tmp_path, monkeypatch
):
    path = tmp_path / "slow.mcap"
    rec, disk_free = _held_writer(monkeypatch, path, queue_size=4)

    def writes():
        for i in range(60):
            if i:
                rec.write_frame(frame_at(i))
            rec.write_imu(imu_sample(i))
            if i % 10 == 0:
                rec.write_label(frame_time(i), "US", "operator")

    caller = threading.Thread(target=writes)
    caller.start()
    caller.join(5.0)
    assert not caller.is_alive()  # every write returned while the writer was stuck
    # The queue holds frames 1-4 (its size) and IMU samples 0-31 (8 light items a heavy
    # one); the other 83 writes are dropped.
    assert rec.stats().dropped_by_kind == {"frame": 55, "imu": 28}
    disk_free.set()
    stats = rec.close()
    assert stats.dropped == 83 and stats.state == "stopped"
    msgs = decode_all(path)
    drops = [d for _, d in msgs[T.EVENTS] if d["kind"] == "drop"]
    assert sum(sum(d["details"].values()) for d in drops) == stats.dropped
    written = len(msgs.get(T.DEPTH, [])) + len(msgs.get(T.IMU, []))
    assert written + stats.dropped == 120
    assert len(msgs[T.LABELS]) == 6  # labels bypass the bounded queue


def test_a_writer_behind_sheds_derived_data_and_keeps_every_raw_item(tmp_path, monkeypatch):
    path = tmp_path / "behind.mcap"
    # room for the raw items alone; the writer falls behind on its first frame
    rec, disk_free = _held_writer(monkeypatch, path, queue_size=200)
    for i in range(1, 60):  # 60 frames' worth: raw and derived, as a session writes them
        t = frame_time(i)
        rec.write_imu(imu_sample(i))
        rec.write_frame(frame_at(i))
        rec.write_processed(i, t, t, np.zeros((3, 3)), np.zeros((100, 100), np.uint8), None, "")
        rec.write_inference(i, t, t, np.full(5, 0.2), {})
        rec.write_features(i, t, {"ok": True})
    behind = rec.stats()
    assert behind.dropped == 0 and behind.shed > 0  # derived data went first
    disk_free.set()
    stats = rec.close()
    assert stats.dropped == 0 and stats.shed == behind.shed
    assert set(stats.shed_by_kind) <= {"processed", "inference", "features"}
    msgs = decode_all(path)
    assert len(msgs[T.DEPTH]) == 60 and len(msgs[T.IMU]) == 59  # every raw item
    derived = sum(len(msgs.get(t, [])) for t in (T.CNN, T.BINARY_IMAGE, T.FEATURES))
    assert derived + stats.shed == 3 * 59
    (shed,) = [d for _, d in msgs[T.EVENTS] if d["kind"] == "shed"]
    assert "raw data kept" in shed["message"] and sum(shed["details"].values()) == stats.shed


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="Linux only")
def test_the_writer_thread_runs_at_the_priority_it_is_given(tmp_path):
    rec = Recorder(tmp_path / "p.mcap", metadata={}, priority=11)
    rec.start()
    try:
        if not rec.scheduling.startswith("SCHED_FIFO"):
            pytest.skip("real-time priority not permitted here")
        tid = rec._thread.native_id
        assert os.sched_getscheduler(tid) == os.SCHED_FIFO
        assert os.sched_getparam(tid).sched_priority == 11
    finally:
        rec.close()


def test_a_backlog_of_imu_samples_finds_room_beside_the_frames(tmp_path, monkeypatch):
    """After a host stall the IMU's backlog comes at once: light items have their own room."""
    path = tmp_path / "burst.mcap"
    rec, disk_free = _held_writer(monkeypatch, path, queue_size=16)
    for k in range(100):  # a second of IMU samples in one burst, six times the queue's size
        rec.write_imu(imu_sample(k))
    assert rec.stats().dropped == 0
    disk_free.set()
    assert rec.close().dropped == 0
    assert len(decode_all(path)[T.IMU]) == 100


def test_labels_are_on_disk_in_the_journal_when_write_label_returns(tmp_path):
    path = tmp_path / "j.mcap"
    rec = Recorder(path, metadata={})
    rec.start()
    rec.write_label(T0, "DS", "operator")
    rec.write_event({"time_ns": T0 + 1, "device": "operator", "kind": "marker", "message": "here"})
    entries = read_journal(rec.journal_path)  # before close, from another file handle
    assert {"type": "label", "time_ns": T0, "mode": "DS", "source": "operator"} in entries
    assert any(e["type"] == "event" and e["message"] == "here" for e in entries)
    rec.close()
    end = read_journal(rec.journal_path)[-1]
    assert end["type"] == "end" and end["state"] == "stopped"  # the state's text, as JSON


def sensor_spans_per_chunk(path) -> list[int]:
    """Log-time span of the sensor messages (depth, IMU) in each chunk of the file."""
    with open(path, "rb") as f:
        topic = {c.id: c.topic for c in make_reader(f).get_summary().channels.values()}
        f.seek(0)
        spans = []
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                times = [
                    m.log_time
                    for m in breakup_chunk(record)
                    if isinstance(m, Message) and topic[m.channel_id] in (T.DEPTH, T.IMU)
                ]
                spans.append(max(times) - min(times) if times else 0)
    return spans


@pytest.mark.realtime
def test_chunks_close_every_second_of_data_and_by_the_wall_clock(tmp_path):
    path = tmp_path / "chunks.mcap"
    write_recording(path, seconds=3.5)
    spans = sensor_spans_per_chunk(path)
    assert len(spans) >= 4
    for span in spans[:-1]:
        assert span <= 1e9 + 2e9 / FPS  # a chunk closes once it holds a second of data

    live = tmp_path / "live.mcap"
    rec = Recorder(live, metadata={}, chunk_interval_s=0.3)
    rec.start()
    rec.write_frame(frame_at(0))
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and T.DEPTH not in open_recording(live).topics:
        time.sleep(0.05)
    seen = open_recording(live)  # still recording: read from disk, unfinished
    assert not seen.complete and seen.topics[T.DEPTH].count == 1
    rec.write_frame(frame_at(1))
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and rec.stats().bytes_per_s == 0:
        time.sleep(0.05)
    assert rec.stats().bytes_per_s > 0 and rec.stats().chunks >= 2
    rec.close()


def test_each_recorder_compresses_at_its_own_level(tmp_path):
    # Two recorders at once, as a replay might run beside a live session's recording.
    fast, small = tmp_path / "fast.mcap", tmp_path / "small.mcap"
    threads = [
        threading.Thread(
            target=write_recording, args=(path,), kwargs={"seconds": 2.0, "zstd_level": level}
        )
        for path, level in ((fast, 1), (small, 19))
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert fast.stat().st_size > 1.1 * small.stat().st_size
    a, b = decode_all(fast), decode_all(small)
    assert a.keys() == b.keys()
    for topic in a:
        # Operator markers bypass the queue: their place among device events is the writer's
        ordered = sorted if topic == T.EVENTS else list
        assert ordered(m.data for m, _ in a[topic]) == ordered(m.data for m, _ in b[topic]), topic


def test_disk_full_stops_cleanly_with_a_clear_message_and_a_readable_file(tmp_path, monkeypatch):
    path = tmp_path / "full.mcap"
    monkeypatch.setattr(TrackedFile, "write", disk_full_after(1_500_000))
    rec = write_recording(path, seconds=3.0, chunk_interval_s=0.2, close=False)
    deadline = time.monotonic() + 5
    while rec.stats().state == "recording" and time.monotonic() < deadline:
        time.sleep(0.02)
    rec.write_frame(frame_at(999))  # after the failure: no exception, nothing blocks
    rec.write_label(T0 + 9 * 10**9, "LG", "operator")
    stats = rec.close()
    assert stats.state == "failed"
    assert stats.message.startswith("disk full: recording stopped after")
    assert "walkcap recover" in stats.message and "\n" not in stats.message
    size = path.stat().st_size
    assert 0 < size <= 1_500_000

    seen = open_recording(path)  # what reached the disk reads back, up to the cut
    assert not seen.complete and seen.topics[T.DEPTH].count > 5
    frames = list(depth_frames(path))
    assert [f.index for f in frames] == list(range(len(frames)))
    monkeypatch.undo()
    report = recover(path)
    assert report.lost_bytes == 0  # the half-written chunk was cut off, nothing damaged
    msgs = decode_all(report.output)
    assert len(msgs[T.DEPTH]) == len(frames)
    labels = {d["time_ns"] for _, d in msgs[T.LABELS]}
    assert T0 + 9 * 10**9 in labels  # journaled after the failure, merged by recover


def test_read_only_folder_is_one_clear_error(tmp_path, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    if os.geteuid() == 0:  # root ignores the mode bits: make the kernel's answer explicit
        real_open = os.open

        def denied(p, *a, **k):
            if str(p).startswith(str(folder)):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(p))
            return real_open(p, *a, **k)

        monkeypatch.setattr(os, "open", denied)
    rec = Recorder(folder / "t.mcap", metadata={})
    with pytest.raises(CaptureError) as e:
        rec.start()
    assert str(e.value) == f"cannot create the recording {folder / 't.mcap'}: Permission denied"
    assert rec.stats().state == "failed"
    rec.write_label(T0, "LG", "operator")  # harmless after the failure
    assert rec.close().state == "failed"
    folder.chmod(0o755)
    assert list(folder.iterdir()) == []


def test_an_existing_recording_is_never_overwritten(tmp_path):
    path = tmp_path / "t.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(CaptureError, match="never overwritten"):
        Recorder(path, metadata={}).start()
    assert path.read_bytes() == b"precious"


def test_bench_record_reports_the_recording_rate(tmp_path):
    from capture.bench.components import bench_record

    r = bench_record(fps=15, seconds=1.0, folder=tmp_path)
    assert r["state"] == "stopped" and r["dropped"] == 0 and r["frames"] == 15
    assert r["mb_per_s"] == pytest.approx(r["bytes"] / 1e6) and r["bytes_per_frame"] > 0
    assert max(r["mb_per_s_by_topic"], key=r["mb_per_s_by_topic"].get) == T.DEPTH


def test_clouds_are_thinned_to_one_point_per_2_cm_voxel(tmp_path):
    from capture.recording.reader import open_recording

    rng = np.random.default_rng(3)
    dense = np.column_stack(
        [rng.uniform(0, 1, 20000), rng.uniform(-0.05, 0.05, 20000), np.zeros(20000)]
    ).astype(np.float32)  # a floor, densely sampled
    path = tmp_path / "c.mcap"
    with Recorder(path, metadata={}) as rec:
        rec.write_processed(0, 1000, 1000, dense, np.zeros((100, 100), np.uint8), None, "")
    (msg,) = open_recording(path).read("/camera/cloud")
    assert 225 <= len(msg.data) <= 300  # 50 x 5 (or 6: the band straddles 0) cells of 2 cm
    cells = np.floor(msg.data / 0.02).astype(int)
    # one point per voxel (storage rounds to 1/1024 m, so a few land in a neighbour)
    assert len(np.unique(cells, axis=0)) >= 0.9 * len(cells)


def test_what_arrives_while_the_trial_closes_is_after_its_end_not_dropped(tmp_path):
    """The operator stops a trial while the last frame's results are on their way: they
    come after the trial's end, and the file does not report the recorder as behind."""
    path = tmp_path / "closing.mcap"
    rec = Recorder(path, metadata={})
    rec.start()
    rec.write_imu(imu_sample(0))
    finish = rec._chunks.finish

    def finish_while_results_arrive(end):
        rec.write_imu(imu_sample(1))  # the file is being finished, the recorder still open
        return finish(end)

    rec._chunks.finish = finish_while_results_arrive
    stats = rec.close()
    assert stats.dropped == 0
    assert not [e for e in decode_all(path).get(T.EVENTS, []) if e["kind"] == "drop"]
    assert len(decode_all(path)[T.IMU]) == 1
