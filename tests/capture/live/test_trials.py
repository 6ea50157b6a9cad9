import pytest

from capture.config import Config
from capture.errors import CaptureError
from capture.live.trials import SubjectInfo, trial_file, trial_metadata


@pytest.mark.parametrize(
    "field, value",
    [
        ("subject", "Jane Doe"),
        ("height_m", 3.0),
        ("sex", "x"),
        ("side", "up"),
        ("trial", 0),
        ("condition", "in door"),
    ],
)
def test_subject_info_validation_names_the_field(field, value):
    info = SubjectInfo(**{field: value})
    with pytest.raises(CaptureError, match=field.split("_")[0]):
        info.validate()


def test_amputee_needs_a_side():
    with pytest.raises(CaptureError, match="side"):
        SubjectInfo(amputee=True).validate()
    SubjectInfo(amputee=True, side="left", residual_limb_cm=30).validate()


def test_a_trial_with_a_file_already_records_under_the_next_number(tmp_path):
    (tmp_path / "S01_indoor_t03_20260101-100000.mcap").write_bytes(b"")
    target = trial_file(tmp_path / "new" / "..", SubjectInfo(trial=3), "next")
    assert target.info.trial == 4 and target.notice and not target.supersedes
    assert target.path.name.startswith("S01_indoor_t04_") and target.path.suffix == ".mcap"
    again = trial_file(tmp_path, SubjectInfo(trial=3), "overwrite")
    assert again.info.trial == 3 and "again" in again.notice
    again.supersedes = ["id-of-t03"]
    config = Config()
    config.session.operator = "op"
    meta = trial_metadata(config, again, {"camera_backend": "mock"}, {"model_hash": "x"})
    assert meta["session"]["operator"] == "op" and meta["session"]["trial"] == 3
    assert meta["session"]["supersedes"] == ["id-of-t03"]
    assert meta["devices"] == {"camera_backend": "mock"} and meta["software"]["model_hash"] == "x"
    with pytest.raises(CaptureError, match="cannot create the recordings folder"):
        trial_file(tmp_path / "S01_indoor_t03_20260101-100000.mcap", SubjectInfo(), "next")


def test_a_recording_keeps_the_configuration_but_not_its_secrets():
    import tomllib

    from capture.config import dumps
    from capture.live.trials import trial_attachments

    config = Config()
    config.lsl.remote_token = "s3cret-t0ken"
    attached = trial_attachments(config, {})["walkcap.toml"].decode()
    assert "s3cret-t0ken" not in attached
    assert 'remote_token = ""  # set, not kept in recordings' in attached
    assert tomllib.loads(attached)["lsl"]["remote_token"] == ""
    assert "s3cret-t0ken" in dumps(config)  # the operator's own saved file keeps it
