"""Recovery: a recording cut anywhere (kill -9, power loss) becomes a valid indexed MCAP
with at most a second of sensor data lost and every journaled label present."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from capture.errors import CaptureError
from capture.recording import NotMcapError
from capture.recording import topics as T
from capture.recording.journal import journal_path, read_journal
from capture.recording.reader import open_recording
from capture.recording.recover import recover
from devices.clock import now_ns
from tests.capture.recording.test_recorder import decode_all
from tests.recording_fixtures import FPS, write_recording

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "trial.mcap"
    write_recording(path, seconds=4.0)
    return path


def depth_per_chunk(path: Path) -> list[tuple[int, int, int]]:
    """(start offset, end offset, depth messages) of every chunk of a complete file."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        depth = next(c.id for c in summary.channels.values() if c.topic == T.DEPTH)
        out = []
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            from mcap.data_stream import ReadDataStream

            chunk = Chunk.read(ReadDataStream(f))
            n = sum(
                1 for r in breakup_chunk(chunk) if isinstance(r, Message) and r.channel_id == depth
            )
            out.append((index.chunk_start_offset, index.chunk_start_offset + index.chunk_length, n))
    return out


def journal_labels(path: Path) -> set:
    return {
        (e["time_ns"], e["mode"], e["source"])
        for e in read_journal(journal_path(path))
        if e["type"] == "label"
    }


def file_labels(msgs) -> set:
    return {(d["time_ns"], d["mode"], d["source"]) for _, d in msgs.get(T.LABELS, [])}


@pytest.mark.parametrize("fraction", [0.0, 0.07, 0.31, 0.5, 0.77, 0.93, 0.9995])
def test_a_file_cut_anywhere_recovers_complete_chunks_and_every_label(
    recording, tmp_path, fraction
):
    data = recording.read_bytes()
    cut_at = max(20, int(len(data) * fraction))  # 20: inside the header record
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:cut_at])
    shutil.copy(journal_path(recording), journal_path(cut))  # fsync'ed per label: complete

    report = recover(cut)
    assert not report.complete and report.valid_bytes <= cut_at
    msgs = decode_all(report.output)  # indexed, every message decodes with its schema
    with open(report.output, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == report.messages

    chunks = depth_per_chunk(recording)
    kept = sum(n for start, end, n in chunks if end <= cut_at)  # chunks wholly before the cut
    reached = sum(n for start, end, n in chunks if start < cut_at)  # ... or started before it
    depth = [m.sequence for m, _ in msgs.get(T.DEPTH, [])]
    assert depth == list(range(len(depth)))  # a clean prefix of the frames
    assert kept <= len(depth) <= reached
    assert reached - len(depth) <= FPS + 1  # at most the open chunk: one second of frames
    assert journal_labels(recording) <= file_labels(msgs)  # no label lost


def test_power_loss_tail_of_zeros_is_cut_off(recording, tmp_path):
    data = recording.read_bytes()
    cut = tmp_path / "power.mcap"
    cut.write_bytes(data[: len(data) // 2] + bytes(300_000))
    report = recover(cut, tmp_path / "out.mcap", journal=journal_path(recording))
    assert report.output == str(tmp_path / "out.mcap")
    assert report.lost_bytes >= 300_000 and report.reason  # the zeros and the cut chunk
    msgs = decode_all(report.output)
    assert len(msgs[T.DEPTH]) > 0 and journal_labels(recording) <= file_labels(msgs)


def test_recovering_a_complete_file_changes_nothing(recording, tmp_path):
    report = recover(recording, tmp_path / "same.mcap")
    assert report.complete and report.lost_bytes == 0
    assert report.labels_added == 0 and report.events_added == 0
    before, after = decode_all(recording), decode_all(report.output)
    assert {t: len(v) for t, v in before.items()} == {t: len(v) for t, v in after.items()}
    assert (
        open_recording(report.output).metadata["session"]
        == open_recording(recording).metadata["session"]
    )
    assert open_recording(report.output).metadata["recovery"]["source_complete"] == "True"


def test_recover_never_overwrites(recording, tmp_path):
    with pytest.raises(CaptureError, match="new file"):
        recover(recording, recording)
    out = tmp_path / "exists.mcap"
    out.write_bytes(b"x")
    with pytest.raises(CaptureError, match="exists"):
        recover(recording, out)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"hello world, not an mcap file at all")
    with pytest.raises(NotMcapError, match="not an MCAP recording"):
        recover(garbage)


RECORD_UNTIL_KILLED = textwrap.dedent("""
    import dataclasses, sys, time
    import numpy as np
    from capture.recording.writer import Recorder
    from devices.simulator.synthetic import synthetic_frame
    from devices.clock import now_ns
    from devices.frames import MODES, ImuSample

    rec = Recorder(sys.argv[1], metadata={"session": {"subject": "K9"}})
    rec.start()
    frames = [synthetic_frame(i, 0) for i in range(4)]
    print("recording", flush=True)
    start = now_ns()
    i = 0
    next_label = start
    while True:
        t = now_ns()
        frame = dataclasses.replace(frames[i % 4], index=i, device_time_ns=t, host_time_ns=t)
        rec.write_frame(frame)
        rec.write_processed(i, t, t, np.zeros((500, 3)), np.zeros((100, 100), np.uint8),
                            np.array([1.0, 0, 0, 0]), "")
        for k in range(2):
            rec.write_imu(ImuSample(host_time_ns=now_ns(), time_ns=t, packet_counter=2 * i + k,
                                    quaternion=np.array([1.0, 0, 0, 0])))
        if t >= next_label:
            rec.write_label(t, MODES[i % 5], "operator")
            next_label += 200_000_000
        i += 1
        time.sleep(max(0.0, (start + i * 1e9 / 45 - now_ns()) * 1e-9))
""")


@pytest.mark.realtime
@pytest.mark.subprocess
def test_kill_9_while_recording_loses_at_most_a_second_and_no_label(tmp_path):
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", RECORD_UNTIL_KILLED, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        assert proc.stdout.readline().strip() == "recording"
        time.sleep(2.7)
        killed_ns = now_ns()  # CLOCK_MONOTONIC: the same clock in both processes
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        proc.kill()
    assert proc.returncode == -signal.SIGKILL

    report = recover(path)
    msgs = decode_all(report.output)
    last_frame = max(m.log_time for m, _ in msgs[T.DEPTH])
    lost_s = (killed_ns - last_frame) * 1e-9
    # one chunk interval, plus one frame and the writer's latency on a busy machine
    print(f"kill -9: {lost_s:.2f} s of frames lost")
    assert lost_s <= 1.0 + 0.25, f"lost {lost_s:.2f} s of frames"
    labels = journal_labels(path)
    assert len(labels) >= 10 and labels <= file_labels(msgs)
    info = open_recording(report.output)
    assert info.metadata["session"] == {"subject": "K9"}
    assert info.metadata["recording"]["topics"][T.DEPTH]  # typed metadata: a dict
