"""The metadata records (capture.recording.metadata): one typed record per name, written and
read through it; a recording's records round-trip byte for byte, old files still read."""

import dataclasses

from capture import config as config_mod
from capture.recording import topics as T
from capture.recording.metadata import (
    RECORDS,
    CameraRecord,
    DevicesRecord,
    Metadata,
    SessionRecord,
    devices_record,
)
from capture.recording.reader import open_recording
from capture.recording.writer import Recorder
from devices.frames import CameraGeometry
from tests.old_recordings import as_version_1
from tests.recording_fixtures import METADATA


def test_every_record_of_a_recording_round_trips_key_order_and_values(recording):
    rec = open_recording(recording)
    names = {r.NAME for r in RECORDS}
    assert {"session", "devices", "software", "camera", "recording"} <= set(rec.metadata)
    for name, values in rec.metadata.items():
        if name not in names:
            continue
        record = getattr(rec.meta, name)
        assert list(record.to_dict().items()) == list(values.items())
        # as MCAP holds it: the same text, key by key, in the same order
        assert T.encode_metadata(record.to_dict()) == T.encode_metadata(values)


def test_the_typed_attributes_read_what_the_writer_wrote(recording):
    meta = open_recording(recording).meta
    assert meta.session.subject == "S07" and meta.session.trial_number == 3
    assert meta.devices.camera_backend == "mock"
    assert meta.software.model_hash == "abc123"
    assert meta.recording.format_version == T.FORMAT_VERSION
    assert isinstance(meta.recording.unix_offset, int)
    assert meta.camera.geometry() == CameraGeometry()
    assert not meta.derivation  # an original: no derivation record


def test_keys_a_record_does_not_name_are_kept_in_their_place():
    values = {"subject": "S01", "a_new_key": [1, 2], "trial": 4, "notes": None}
    record = SessionRecord.from_dict(values)
    assert record.extra == {"a_new_key": [1, 2]}
    assert list(record.to_dict().items()) == list(values.items())
    assert record.has("notes") and not record.has("age")
    assert "age" not in record.to_dict()  # a key the file lacks is not added
    moved = record.replaced(trial=5, operator="RA")
    assert list(moved.to_dict()) == ["subject", "a_new_key", "trial", "notes", "operator"]


def test_a_damaged_or_missing_record_reads_as_an_empty_one():
    meta = Metadata.from_dict({"session": "not a mapping"})
    assert not meta.session and meta.session.to_dict() == {}
    assert meta.devices.rates_hz == {} and meta.session.trial_number is None


def test_the_devices_record_has_one_builder_for_live_and_simulated_sessions():
    config = config_mod.Config()
    config.camera.backend = "mock"
    live = devices_record(config, camera_details={"serial": "x"}, imu_info={"fw": 1})
    assert list(live.to_dict()) == [
        "camera_backend",
        "camera_fps",
        "camera_use_case",
        "camera_details",
        "imu_backend",
        "imu_port",
        "imu_rate_hz",
        "imu_info",
        "imu_details",
        "simulator",
    ]
    assert live.camera_details == {"serial": "x"} and live.imu_details == {}
    simulated = devices_record(config, simulated=True)
    assert simulated.to_dict() == {
        "camera_backend": "mock",
        "camera_fps": config.camera.fps,
        "imu_backend": "synthetic",
        "imu_rate_hz": config.imu.rate_hz,
        "simulator": T.jsonable(dataclasses.asdict(config.simulator)),
    }
    assert simulated.rates_hz == {"camera": config.camera.fps, "imu": config.imu.rate_hz}


def test_the_camera_record_is_the_geometry_and_its_rays():
    g = CameraGeometry(width=10, height=8, serial="abc")
    record = CameraRecord.of(g, T.RAYS_ATTACHMENT, 7)
    assert record.geometry() == g and record.from_frame_index == 7
    assert list(record.to_dict())[-2:] == ["rays_attachment", "from_frame_index"]


def test_a_version_1_file_reads_through_the_typed_records(tmp_path):
    new = tmp_path / "S07_indoor_t01.mcap"
    rec = Recorder(new, metadata=METADATA)
    rec.start()
    rec.close()
    (tmp_path / "old").mkdir()
    old = open_recording(as_version_1(new, tmp_path / "old" / new.name))
    assert old.format_version == "1"
    # version 1 held text: the records hold what the reader gives (typed by versions)
    for record in old.meta.records():
        assert record.to_dict() == old.metadata.get(record.NAME, {})
    assert old.meta.session.trial_number == 3 and old.meta.recording.unix_offset is not None
    assert old.meta.devices == DevicesRecord.from_dict(METADATA["devices"])
    assert old.trial == ("S07", "indoor", 3)
