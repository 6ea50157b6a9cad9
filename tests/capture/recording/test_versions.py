"""Format versions: a version 1 file is read through capture.recording.versions and
nowhere else; a file of a newer version is refused with one line."""

import numpy as np
import pytest
from mcap.writer import Writer

from capture.corpus.export import tables
from capture.corpus.trials import read_trial
from capture.errors import CaptureError
from capture.recording import lineage, versions
from capture.recording import topics as T
from capture.recording.checking import check
from capture.recording.reader import open_recording
from capture.recording.topics import FORMAT_VERSION
from capture.recording.writer import Recorder
from devices.frames import MODES
from tests.old_recordings import as_version_1
from tui import cli

T0 = 3_000_000_000
N = 12


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A file written now, and the same trial as version 1 wrote it."""
    folder = tmp_path_factory.mktemp("versions")
    new = folder / "S03_indoor_t01.mcap"
    rec = Recorder(new, metadata={"session": {"subject": "S03", "condition": "indoor"}})
    rec.start()
    rec.write_label(T0, "LG", "operator")
    for i in range(N):
        t = T0 + i * 66_000_000
        fused = {"frame_index": i - 1, "decision": MODES[1]} if i else {}
        rec.write_inference(i, t, t + 1_000_000, np.eye(5)[1], fused)
    rec.close()
    (folder / "old").mkdir()
    old = as_version_1(new, folder / "old" / new.name)
    return new, old


def test_files_written_now_name_the_current_version(files):
    new, old = files
    assert FORMAT_VERSION == "5"
    assert open_recording(new).format_version == FORMAT_VERSION
    assert open_recording(old).format_version == "1"


def test_a_file_without_record_digests_reads_unchecked_as_it_did(files, tmp_path):
    """Versions 1 and 2 wrote no digests: their records are read as they are, and such a
    file is complete; a version 3 file without them is damaged, record by record."""
    new, _ = files
    for version in ("1", "2"):
        old = as_version_1(new, tmp_path / f"v{version}.mcap", version=version)
        rec = open_recording(old)
        assert rec.format_version == version and rec.damaged == []
        assert check(old).complete
        assert rec.metadata["session"]["subject"] == "S03"
    stripped = as_version_1(new, tmp_path / "v3.mcap", version="3")
    damaged = {d.record for d in check(stripped).damaged}
    assert {"header", "metadata session", "metadata recording"} <= damaged
    assert {d.record for d in open_recording(stripped).damaged} >= damaged


def test_a_version_1_file_is_upgraded_on_reading(files):
    new, old = files
    rec = open_recording(old)
    [raw] = [m.data for m in rec.messages([T.FUSED], raw=True)][:1]
    assert "source_frame_index" not in raw  # as stored
    fused = [m.data for m in rec.messages([T.FUSED])]
    assert all(d["source_frame_index"] == d["frame_index"] for d in fused)
    # version 1 did not say which frame produced a decision: the frame it refers to
    assert list(tables(old)["frames"].decision_at_frame[:-1]) == list(range(N - 1))
    assert list(tables(new)["frames"].decision_at_frame[:-1]) == list(range(1, N))
    assert list(read_trial(old).frames.decision) == list(read_trial(new).frames.decision)


def test_no_other_code_reads_version_1_messages(files, monkeypatch):
    _, old = files
    monkeypatch.setattr(versions, "upgrade_message", lambda topic, data: data)
    with pytest.raises(KeyError, match="source_frame_index"):
        tables(old)


def test_a_version_1_copy_is_known_by_its_name_and_a_current_one_by_its_metadata(files, tmp_path):
    new, _ = files
    old_copy = as_version_1(new, tmp_path / "S03_indoor_t01.recovered.mcap")
    member = lineage.describe(open_recording(old_copy))
    assert member.kind == lineage.RECOVERED and member.source_name == new.name
    assert member.id == f"file:{old_copy.resolve()}"  # its "recording" id is its source's
    plain = tmp_path / "S03_indoor_t01.replay.mcap"
    plain.write_bytes(new.read_bytes())  # the name of a replay, no derivation: an original
    assert lineage.describe(open_recording(plain)).kind == lineage.RECORDING


def test_version_1_metadata_text_is_typed(tmp_path):
    """A version 1 file without JSON values: plain strings, lists as JSON text."""
    plain = tmp_path / "plain.mcap"
    with open(plain, "wb") as g:
        w = Writer(g)
        w.start()
        w.add_metadata("session", {"trial": "4", "tags": '["a", "b"]', "note": "[x"})
        w.add_metadata("recording", {"format_version": "1", "unix_offset_ns": "5"})
        w.finish()
    rec = open_recording(plain)
    assert rec.format_version == "1"
    assert rec.metadata["session"] == {"trial": 4, "tags": ["a", "b"], "note": "[x"}
    assert rec.unix_offset_ns == 5


def test_a_newer_version_is_refused_with_one_line(files, tmp_path, capsys):
    new, _ = files
    newer = str(int(FORMAT_VERSION) + 1)
    future = as_version_1(new, tmp_path / "future.mcap", version=newer)
    with pytest.raises(CaptureError, match=f"recording format '{newer}', newer than this walkcap"):
        open_recording(future)
    assert cli.main(["info", str(future)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "update walkcap" in err and "Traceback" not in err


def test_a_version_4_files_tf_holds_the_imus_orientation_and_reads_as_the_cameras(tmp_path):
    """Up to version 4 /tf held the IMU's orientation: read, it is the camera's, with the
    mounting the file's software record names (not the nominal one)."""
    from capture.recording.reader import open_recording as opened
    from devices.config import MountingConfig
    from devices.rotations import quat_from_euler
    from inference.config import PreprocessConfig
    from inference.preprocess import camera_orientation
    from inference.preprocess import metadata as preprocess_metadata
    from tests.old_recordings import as_version_4

    mounting = MountingConfig(roll_deg=3.0, pitch_deg=28.0, yaw_deg=-2.0)
    rng = np.random.default_rng(4)
    imu = [quat_from_euler(*rng.uniform(-1.5, 1.5, 3)) for _ in range(N)]
    new = tmp_path / "S03_indoor_t01.mcap"
    software = {"preprocess": preprocess_metadata(PreprocessConfig(), mounting)}
    rec = Recorder(new, metadata={"session": {"subject": "S03"}, "software": software})
    rec.start()
    cloud, image = np.zeros((0, 3), np.float32), np.zeros((100, 100), np.uint8)
    for i, q in enumerate(imu):
        t = T0 + i * 66_000_000
        rec.write_processed(i, t, t + 1_000_000, cloud, image, camera_orientation(q, mounting), "")
    rec.close()
    old = as_version_4(new, tmp_path / "old.mcap", lambda k: imu[k])
    stored = [T.quaternion_from_transform(m.data) for m in opened(old).messages([T.TF], raw=True)]
    np.testing.assert_allclose(stored, imu)  # as version 4 wrote it
    assert opened(old).format_version == "4" and check(old).complete
    read_old = [m.data for m in opened(old).messages([T.TF])]
    read_new = [m.data for m in opened(new).messages([T.TF])]
    np.testing.assert_allclose(read_old, read_new, atol=1e-9)
    nominal = [camera_orientation(q) for q in imu]
    assert np.max(np.abs(np.asarray(nominal) - np.asarray(read_old))) > 0.01
    elevation = read_trial(old).frames.camera_elevation_deg
    np.testing.assert_allclose(elevation, read_trial(new).frames.camera_elevation_deg)
