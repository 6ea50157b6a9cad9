"""The fault suite: device faults during a recording, full disks, cut and corrupt files.

Each fault gets one clear message, costs nothing already captured, and leaves the
recording readable. Devices are the real mock backends (the IMU emulator behind a pty).
"""

import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from capture.corpus.trials import read_trial
from capture.recording.journal import check_journal
from capture.recording.reader import open_recording
from tests.capture.live.sessions import events_of, recording_in
from tests.waiting import wait_for


@pytest.mark.realtime
def test_imu_unplug_and_replug_during_a_recording(tmp_path):
    with recording_in(tmp_path) as trial:
        session, path = trial.session, trial.path
        session.set_label("LG")
        time.sleep(1.0)
        session._imu.inject("disconnect")
        wait_for(lambda: session.snapshot().imu.state == "lost", 1.5, what="the unplug seen")
        frames_while_lost = session.snapshot().frames
        session.set_label("US")  # the operator keeps labelling
        time.sleep(0.8)
        assert session.snapshot().frames > frames_while_lost  # the camera keeps recording
        session._imu.inject("reconnect")
        wait_for(lambda: session.snapshot().imu.state == "ok", 5.0, what="the reconnect")
        time.sleep(0.5)
    stats = trial.stats
    assert stats.state == "stopped"
    kinds = [e["kind"] for e in events_of(path)]
    assert "lost" in kinds and "reconnected" in kinds
    trial = read_trial(path)
    assert [c[1] for c in trial.label_changes if c[2] == "operator"] == ["LG", "US"]
    imu_times = [m.log_time_ns for m in open_recording(path).messages(["/imu"])]
    assert np.max(np.diff(imu_times)) > 0.5e9  # the gap is in the file, samples on both sides


@pytest.mark.realtime
def test_corrupted_serial_bytes_are_counted_and_capture_goes_on(tmp_path):
    with recording_in(tmp_path) as trial:
        session, path = trial.session, trial.path
        time.sleep(0.5)
        session._imu.inject("corrupt", count=5, garbage=b"\xfa\xff\x36\xff\x00garbage")
        time.sleep(1.0)
        snap = session.snapshot()
    assert snap.imu.details["checksum_errors"] >= 1
    assert snap.imu.state in ("ok", "degraded")
    assert any(e["kind"] in ("checksum_error", "resync") for e in events_of(path))
    rec = open_recording(path)
    assert rec.topics["/imu"].count > 100  # ~1.5 s at 100 Hz, a handful lost at most


@pytest.mark.realtime
def test_camera_stall_is_reported_and_the_imu_keeps_recording(tmp_path):
    with recording_in(tmp_path) as trial:
        session, path = trial.session, trial.path
        time.sleep(0.5)
        session._camera.inject("stall", seconds=2.0)
        wait_for(lambda: session.snapshot().camera.state == "degraded", 2.0)
        time.sleep(1.8)
        wait_for(lambda: session.snapshot().camera.state == "ok", 3.0)
    assert "stall" in [e["kind"] for e in events_of(path)]
    assert open_recording(path).topics["/imu"].count > 250  # 100 Hz all along


@pytest.fixture
def small_disk(tmp_path):
    """A 3 MB filesystem that fills within seconds of recording (needs root to mount)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a size-limited tmpfs needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], capture_output=True
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount tmpfs here: {done.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], capture_output=True)


@pytest.mark.realtime
def test_disk_full_stops_the_recording_cleanly_and_keeps_it_readable(small_disk):
    with recording_in(small_disk) as trial:
        session, path = trial.session, trial.path
        session.set_label("LG")
        wait_for(lambda: session.snapshot().recording.state == "failed", 30.0)
        snap = session.snapshot()
        assert snap.running  # devices and pipeline go on; only the file stopped
    stats = trial.stats
    assert stats.state == "failed"
    assert "full" in stats.message.lower() or "space" in stats.message.lower()
    assert "\n" not in stats.message
    rec = open_recording(path)  # what was written stays readable, without recover
    assert rec.topics["/camera/depth"].count > 5
    assert [c[1] for c in read_trial(path).label_changes] == ["LG"]


def run_cli(*args, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "tui.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def one_clear_line(out):
    assert out.returncode in (1, 2), out.stderr  # a user error; 70 would be a crash
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr
    lines = [line for line in out.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    return lines[0]


@pytest.fixture(scope="module")
def garbage_and_cut(tmp_path_factory):
    from tests.recording_fixtures import write_recording

    folder = tmp_path_factory.mktemp("files")
    good = folder / "good.mcap"
    write_recording(good, seconds=3.0)
    cut = folder / "cut.mcap"
    data = good.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    garbage = folder / "garbage.mcap"
    garbage.write_bytes(os.urandom(5000))
    flipped = folder / "flipped.mcap"
    raw = bytearray(data)
    for i in range(2000, len(raw), 997):
        raw[i] ^= 0x5A
    flipped.write_bytes(bytes(raw))
    return good, cut, garbage, flipped


@pytest.mark.parametrize(
    "command", [["info"], ["replay", "--fast"], ["eval", "recordings"], ["recover"]]
)
@pytest.mark.subprocess
def test_garbage_files_are_one_clear_line(garbage_and_cut, command):
    _, _, garbage, _ = garbage_and_cut
    line = one_clear_line(run_cli(*command, str(garbage)))
    assert "garbage.mcap" in line


@pytest.mark.subprocess
@pytest.mark.parametrize("command", [["info"], ["eval", "recordings", "--reference", "terrain"]])
def test_cut_files_are_read_up_to_the_cut(garbage_and_cut, command):
    _, cut, _, _ = garbage_and_cut
    out = run_cli(*command, str(cut))
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.subprocess
@pytest.mark.parametrize("command", [["info"], ["eval", "recordings", "--reference", "terrain"]])
def test_corrupted_bytes_inside_a_file_never_give_a_traceback(garbage_and_cut, command):
    _, _, _, flipped = garbage_and_cut
    out = run_cli(*command, str(flipped))
    if out.returncode != 0:
        one_clear_line(out)
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr


def _chunk_spans_ns(path) -> list[int]:
    """The log-time span of every complete chunk in a (possibly cut-off) MCAP file."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    spans = []
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    spans.append(record.message_end_time - record.message_start_time)
        except Exception:  # the cut-off end: the complete chunks are what is on disk
            pass
    return spans


@pytest.mark.realtime
@pytest.mark.slow
@pytest.mark.subprocess
def test_kill_9_while_recording_then_recover_loses_at_most_a_second_and_no_label(tmp_path):
    """A real `walkcap record` process killed with SIGKILL, as a power loss would.

    What a kill can lose is the open chunk; every chunk closes once it holds a second of
    data, so the loss is bounded by the data's own time, whatever the machine's load.
    """
    import signal

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tui.cli",
            "record",
            "--out",
            str(tmp_path),
            "--auto-label",
            "--duration",
            "600",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stderr.readline()  # "recording PATH"
        assert line.startswith("recording "), line + proc.stderr.read()
        path = tmp_path / os.path.basename(line.split(" ", 1)[1].strip())

        def on_disk() -> int:
            try:
                return open_recording(path).topics["/camera/depth"].count
            except Exception:  # nothing complete yet
                return 0

        # Depth on disk: a bounded wait on the file, not on a clock.
        wait_for(lambda: on_disk() >= 30, 300, 0.5)
        proc.send_signal(signal.SIGSTOP)  # what is on disk now is what the kill leaves
        seen = on_disk()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    journal = check_journal(str(path) + ".journal.jsonl").entries  # each line its CRC
    labels_journaled = [(e["time_ns"], e["mode"]) for e in journal if e.get("type") == "label"]
    assert labels_journaled

    spans = _chunk_spans_ns(path)
    # a chunk closes once its sensor data spans a second (events and decisions stamped a
    # little before or after lie in it too): what a kill loses is about a second of data
    assert spans and max(spans) < 1.5e9
    out = run_cli("recover", str(path))
    assert out.returncode == 0, out.stderr
    fixed = path.with_suffix(".recovered.mcap")
    assert fixed.name in out.stdout + out.stderr
    rec = open_recording(fixed)
    assert rec.topics["/camera/depth"].count >= seen > 0  # nothing on disk is lost
    labels = [(c[0], c[1]) for c in read_trial(fixed).label_changes]
    for label in labels_journaled:
        assert label in labels


@pytest.mark.subprocess
def test_a_bad_model_file_is_one_clear_line(tmp_path):
    bad = tmp_path / "broken.pt"
    bad.write_bytes(b"not a torch file at all")
    line = one_clear_line(
        run_cli("record", "--duration", "1", "--out", str(tmp_path), "--model", str(bad))
    )
    assert "broken.pt" in line


@pytest.mark.subprocess
def test_a_bad_configuration_stops_record_before_any_device_opens(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[imu]\nrate_hz = 'fast'\n")
    line = one_clear_line(run_cli("--config", str(cfg), "record", "--duration", "1"))
    assert "imu.rate_hz" in line
