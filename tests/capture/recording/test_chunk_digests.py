"""Chunk digests: `info` on a finished file reads no chunk and says what the scan says."""

import importlib
import json

import numpy as np
import pytest

from capture.recording import _mcap
from capture.recording import topics as T
from capture.recording.chunk_digests import CHUNK_DIGESTS
from capture.recording.reader import open_recording
from capture.recording.summary import summary
from capture.recording.writer import Recorder
from devices.base import DeviceEvent
from tests import recording_fixtures as F
from tui import cli

summary_module = importlib.import_module("capture.recording.summary")

METADATA = {**F.METADATA, "devices": {"camera_fps": 45.0, "imu_rate_hz": 100}}


def _trial(path, *, metadata=METADATA, frames: int = 120):
    """Frames and IMU samples with gaps and a host stall, flags, labels and events."""
    rec = Recorder(
        path,
        metadata=metadata,
        attachments=F.ATTACHMENTS,
        queue_size=100_000,
        chunk_interval_s=0.25,
        zstd_level=1,
    )
    rec.start()
    labels = F.label_schedule(frames / F.FPS)
    k = 0
    for i in range(frames):
        t = F.frame_time(i)
        while F.T0 + k * 1e9 / F.IMU_HZ <= t:
            if k not in (30, 31, 32):  # three packets lost
                sample = F.imu_sample(k)
                if k > 150:  # delivered after a host stall
                    sample.host_time_ns += 200_000_000
                rec.write_imu(sample)
            k += 1
        while labels and labels[0][0] <= t:
            rec.write_label(*labels.pop(0))
        if i in (40, 41):  # two frames lost
            continue
        frame = F.frame_at(i)
        rec.write_frame(frame)
        flag = "no orientation" if i % 17 == 5 else ("stale orientation" if i == 60 else "")
        rec.write_processed(
            i, t, frame.host_time_ns, np.zeros((10, 3)), np.zeros((8, 8), np.uint8), None, flag
        )
        if i == 10:
            rec.write_event(DeviceEvent(t, "imu", "gap", "3 samples missing", {"missing": 3}))
            rec.write_event({"time_ns": t, "device": "operator", "kind": "marker", "message": "m"})
    rec.close()
    return path


def _info(path, capsys) -> tuple[str, str]:
    assert cli.main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert cli.main(["info", "--json", str(path)]) == 0
    return text, capsys.readouterr().out


def test_info_from_the_digests_decompresses_no_chunk_and_prints_what_the_scan_prints(
    tmp_path, capsys, monkeypatch
):
    path = _trial(tmp_path / "S07_indoor_t03.mcap")
    rec = open_recording(path)
    fast = summary_module._from_digests(rec)
    slow = summary_module._read_through(rec)
    assert fast is not None and fast == slow
    assert fast.losses[T.IMU].missing == 3 and fast.losses[T.IMU].late
    assert fast.losses[T.DEPTH].missing == 2
    assert fast.flags == {"no orientation": 7, "stale orientation": 1}
    assert fast.events == {"gap": 1, "marker": 1} and len(fast.labels) > 3

    def refused(*args):
        raise AssertionError("a chunk was decompressed")

    monkeypatch.setattr(_mcap, "_decompress", refused)
    from_digests = _info(path, capsys)
    monkeypatch.undo()
    monkeypatch.setattr(summary_module, "_from_digests", lambda rec: None)
    assert _info(path, capsys) == from_digests  # text and --json, byte for byte
    assert CHUNK_DIGESTS not in from_digests[0] and CHUNK_DIGESTS not in rec.metadata


def test_a_flipped_byte_in_a_chunk_is_found_by_the_scan(tmp_path):
    """The region's CRC fails: the digests prove nothing, the scan names the damage."""
    from mcap.reader import make_reader

    path = _trial(tmp_path / "S07_indoor_t03.mcap")
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[2]
    data = bytearray(path.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x10
    path.write_bytes(bytes(data))
    rec = open_recording(path)
    assert summary_module._from_digests(rec) is None
    s = summary(rec)
    assert s.damaged and s.losses is None


def test_files_without_digests_are_read_through(tmp_path):
    """No configured rates (gaps need every item then), a cut file, a copy: the scan."""
    from capture.recording.copy import copy_recording
    from capture.recording.lineage import CORRECTED

    plain = _trial(tmp_path / "S07_indoor_t01.mcap", metadata=F.METADATA, frames=60)
    assert summary_module._from_digests(open_recording(plain)) is None
    assert summary(open_recording(plain)).losses is not None

    path = _trial(tmp_path / "S07_indoor_t03.mcap", frames=60)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    assert summary_module._from_digests(open_recording(cut)) is None

    copy = copy_recording(path, tmp_path / "copy.mcap", kind=CORRECTED, how="test")
    rec = open_recording(copy)
    assert summary_module._from_digests(rec) is None
    assert summary(rec).labels == summary(open_recording(path)).labels


def test_the_official_reader_reads_a_file_with_digests(tmp_path):
    """The digests are one ordinary metadata record: mcap's reader reads every message."""
    from mcap.reader import make_reader

    path = _trial(tmp_path / "S07_indoor_t03.mcap", frames=60)
    with open(path, "rb") as f:
        reader = make_reader(f)
        names = [m.name for m in reader.iter_metadata()]
        n = sum(1 for _ in reader.iter_messages())
        assert n == reader.get_summary().statistics.message_count
    assert names.count(CHUNK_DIGESTS) == 1
    digest = next(
        m for m in make_reader(open(path, "rb")).iter_metadata() if m.name == CHUNK_DIGESTS
    )
    assert json.loads(digest.metadata["regions"])[0][0] == 0


@pytest.mark.parametrize("cut", [0.3, 0.9])
def test_a_file_cut_and_recovered_has_no_stale_digest(tmp_path, cut):
    from capture.recording.recover import recover

    path = _trial(tmp_path / "S07_indoor_t03.mcap", frames=60)
    part = tmp_path / "S07_indoor_t04.mcap"
    part.write_bytes(path.read_bytes()[: int(path.stat().st_size * cut)])
    out = recover(part).output
    with open(out, "rb") as f:
        from mcap.reader import make_reader

        assert CHUNK_DIGESTS not in [m.name for m in make_reader(f).iter_metadata()]
