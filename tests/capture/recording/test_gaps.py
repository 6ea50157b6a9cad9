"""Loss counted on the devices' own sequences: gaps (data missing) apart from late delivery
(the host stalled, nothing missing), one definition live, in `walkcap info` and its JSON."""

from __future__ import annotations

import json

import pytest

from capture.live.alarms import TrialAlarms
from capture.recording.gaps import LossCounter, missing_between, recording_loss, stream_loss
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from tests.recording_fixtures import METADATA, T0, frame_at, imu_sample
from tui import cli

MS = 1_000_000
PERIOD = 0.01  # 100 Hz


def test_a_stream_without_a_sequence_has_its_gaps_found_by_its_times():
    period = 0.022
    t = [k * 22 * MS for k in range(100) if not 50 <= k < 53]  # three frames missing
    (gap,) = stream_loss([(None, x, x) for x in t], period, None).gaps
    assert (gap.start_ns, gap.missing) == (t[49], 3) and gap.length_s == pytest.approx(0.088)
    regular = [(None, k * 10, k * 10) for k in range(10)]
    assert stream_loss(regular, 10e-9, None).gaps == []


def test_a_host_stall_with_every_sample_there_is_late_delivery_not_a_gap():
    counter = LossCounter(PERIOD, 1 << 16)
    for k in range(100):  # 100 Hz on the device; the host stalls 0.5 s after sample 49
        host = T0 + k * 10 * MS + (500 * MS if k >= 50 else 0)
        counter.add(k, T0 + k * 10 * MS, host)
    assert counter.loss.gaps == [] and counter.loss.missing == 0
    (late,) = counter.loss.late
    assert late.length_s == pytest.approx(0.51)


def test_a_skipped_counter_is_a_gap_of_the_samples_missing():
    counter = LossCounter(PERIOD, 1 << 16)
    for k in [*range(10), *range(13, 20)]:  # 10, 11, 12 never arrive
        counter.add(k, T0 + k * 10 * MS, T0 + k * 10 * MS + MS)
    (gap,) = counter.loss.gaps
    assert gap.missing == 3 and gap.length_s == pytest.approx(0.04)
    assert gap.start_ns == T0 + 9 * 10 * MS and counter.loss.late == []


def test_a_wrapping_counter_a_long_gap_and_a_restarted_sequence():
    # 65535 -> 0: no gap
    assert missing_between(65535, 0, 10 * MS, PERIOD, 1 << 16) == 0
    # 700 s at 100 Hz: the counter wrapped once and more; the device time says how often
    dt = 700 * 10**9
    assert missing_between(5, (5 + 70_000) % 65536, dt, PERIOD, 1 << 16) == 69_999
    # a power-cycled device counts from 0 again: its time says one sample went by
    assert missing_between(4000, 0, 20 * MS, PERIOD, 1 << 16) == 1
    # a camera's frame index never wraps
    assert missing_between(7, 10, 3 * 66 * MS, 1 / 15, None) == 2


def _write(path, imu, frames):
    """A recording of IMU samples and depth frames as given (no derived topics)."""
    metadata = {**METADATA, "devices": {"camera_fps": "45.0", "imu_rate_hz": "100.0"}}
    rec = Recorder(path, metadata=metadata, queue_size=100_000, cloud_voxel_m=0.0)
    rec.start()
    for s in imu:
        rec.write_imu(s)
    for f in frames:
        rec.write_frame(f)
    rec.close()


def test_info_text_json_and_the_live_alarms_count_alike(tmp_path, capsys):
    imu = []
    for k in range(300):
        if k in (120, 121, 122):  # three samples the file lacks
            continue
        s = imu_sample(k)
        if k >= 200:  # the host stalled 0.4 s: every sample still there, late
            s.host_time_ns += 400 * MS
        imu.append(s)
    frames = [frame_at(i) for i in range(40) if i not in (20, 21)]
    path = tmp_path / "S07_indoor_t03.mcap"
    _write(path, imu, frames)

    loss = recording_loss(open_recording(path))
    assert [g.missing for g in loss["/imu"].gaps] == [3]
    assert len(loss["/imu"].late) == 1
    assert [g.missing for g in loss["/camera/depth"].gaps] == [2]
    assert loss["/camera/depth"].late == []

    alarms = TrialAlarms(tmp_path, {"camera": 1 / 45, "imu": 0.01})
    alarms.new_trial()
    for s in imu:
        alarms.sample("imu", s.packet_counter, s.time_ns, s.host_time_ns)
    for f in frames:
        alarms.sample("camera", f.index, f.device_time_ns, f.host_time_ns)
    alarms.end_trial()
    assert alarms.trial_gaps == {"camera": 1, "imu": 1}
    assert alarms.trial_late == {"camera": 0, "imu": 1}

    assert cli.main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "/camera/depth 1, 2 missing" in text and "/imu 1, 3 missing" in text
    assert "late        /imu 1 (longest 0.41 s)" in text
    assert cli.main(["info", "--json", str(path)]) == 0
    data = json.loads(capsys.readouterr().out)
    data = data[0] if isinstance(data, list) else data
    assert [g["missing"] for g in data["gaps"]["/imu"]] == [3]
    assert [g["missing"] for g in data["gaps"]["/camera/depth"]] == [2]
    assert len(data["late"]["/imu"]) == 1 and data["late"]["/camera/depth"] == []


def test_export_counts_the_same_loss(tmp_path):
    from capture.corpus import export

    imu = [imu_sample(k) for k in range(200) if k not in (50, 51)]
    for s in imu[120:]:
        s.host_time_ns += 300 * MS
    path = tmp_path / "S07_indoor_t03.mcap"
    _write(path, imu, [frame_at(i) for i in range(20)])
    (row,) = export.tables(path)["trials"].to_dict("records")
    assert (row["imu_gaps"], row["imu_missing"], row["imu_late"]) == (1, 2, 1)
    assert row["imu_longest_gap_s"] == pytest.approx(0.03)
    assert (row["camera_gaps"], row["camera_missing"], row["camera_late"]) == (0, 0, 0)
