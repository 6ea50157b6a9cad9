import dataclasses
from pathlib import Path

import pytest

from capture import config as cfg
from capture.errors import ConfigError
from devices import camera, imu
from inference import fusion

REFERENCE = Path(__file__).resolve().parents[2] / "docs" / "configuration.md"


def _refused(path, text: str, match: str) -> None:
    """A file of `text` is refused with a message that matches `match`."""
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        cfg.load(path)


def test_defaults_run_out_of_the_box():
    c = cfg.load(None)
    assert c.camera.backend == "mock" and c.imu.backend == "mock"
    assert c.camera.fps == 15.0
    assert c.fusion.transition[0] == [0.80, 0.05, 0.05, 0.05, 0.05]


def test_reads_local_walkcap_toml(tmp_path):
    (tmp_path / "walkcap.toml").write_text("[camera]\nfps = 45\n[imu]\nport = '/dev/ttyUSB0'\n")
    c = cfg.load(None)
    assert c.camera.fps == 45.0 and isinstance(c.camera.fps, float)
    assert c.imu.port == "/dev/ttyUSB0"
    assert c.source == "walkcap.toml"


@pytest.mark.parametrize(
    "text, key",
    [
        ("[camera]\nfpss = 3\n", "camera.fpss"),
        ("[nosuch]\nx = 1\n", "nosuch"),
        ("[imu]\nbaudrate = 'fast'\n", "imu.baudrate"),
        ("[imu]\nbaudrate = 1.5\n", "imu.baudrate"),
        ("[simulator]\nrealtime = 1\n", "simulator.realtime"),
        ("[fusion]\ntransition = [[1, 'a']]\n", "fusion.transition[0][1]"),
        ("camera = 3\n", "camera"),
    ],
)
def test_bad_keys_and_types_name_the_key(tmp_path, text, key):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as e:
        cfg.load(p)
    assert key in str(e.value)


def test_invalid_toml_names_the_file(tmp_path):
    p = tmp_path / "c.toml"
    _refused(p, "[camera\n", "c.toml")


def test_override_checks_types():
    c = cfg.Config()
    cfg.override(c, "camera.fps", 30)
    assert c.camera.fps == 30.0
    with pytest.raises(ConfigError, match="camera.fps"):
        cfg.override(c, "camera.fps", "x")
    with pytest.raises(ConfigError, match="camera.nope"):
        cfg.override(c, "camera.nope", 1)


def test_save_then_load_round_trips(tmp_path):
    c = cfg.Config()
    c.mounting.pitch_deg = 31.5
    c.keys.quit = "x"
    path = cfg.save(c, tmp_path / "w.toml")
    back = cfg.load(path)
    assert cfg.to_dict(back) == cfg.to_dict(c)


def test_fusion_hysteresis_is_read_and_checked(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[fusion]\nmethod = 'steady+hysteresis'\nhysteresis = 0.9\n")
    c = cfg.load(p)
    assert c.fusion.method == "steady+hysteresis" and c.fusion.hysteresis == 0.9
    _refused(p, "[fusion]\nhysteresis = 1.0\n", "0 <= hysteresis < 1")


def test_fusion_geometry_keys_are_read_and_checked(tmp_path):
    p = tmp_path / "c.toml"
    text = (
        "[fusion]\nmethod = 'steady+geometry'\ngeometry_hysteresis = 0.7\ngeometry_evidence = 0.3\n"
    )
    p.write_text(text)
    c = cfg.load(p)
    assert c.fusion.method == "steady+geometry"
    assert (c.fusion.geometry_hysteresis, c.fusion.geometry_evidence) == (0.7, 0.3)
    fusion = c.fusion.make()  # the live session's, with both keys
    assert (fusion.method, fusion.hysteresis, fusion.geometry_evidence) == (
        c.fusion.method,
        0.7,
        0.3,
    )
    _refused(p, "[fusion]\ngeometry_hysteresis = 1.5\n", "0 <= geometry_hysteresis < 1")
    _refused(p, "[fusion]\ngeometry_evidence = 0\n", "0 < geometry_evidence <= 1")


def test_the_configuration_reference_is_the_generated_one():
    assert REFERENCE.read_text() == cfg.reference(), (
        f"docs/configuration.md is not the configuration's fields: `{cfg.REFERENCE_COMMAND}`"
    )


def test_the_reference_shows_every_key_with_its_doc_and_default():
    text = cfg.reference()
    for name, section in cfg.sections():
        assert f"## [{name}]" in text
        for key in dataclasses.fields(section):
            assert f"| `{key.name}` |" in text and key.metadata["doc"], f"{name}.{key.name}"
    assert "| `fps` | `15.0` | frame rate" in text


@pytest.mark.parametrize(
    "section, key, registry",
    [("camera", "backend", camera.BACKENDS), ("imu", "backend", imu.BACKENDS)],
)
def test_backend_names_come_from_the_registries(monkeypatch, section, key, registry):
    monkeypatch.setitem(registry, "lab-built", registry[next(iter(registry))])
    assert getattr(cfg.from_dict({section: {key: "lab-built"}}), section).backend == "lab-built"
    assert "lab-built" in cfg.reference() and "lab-built" in cfg.documented(cfg.Config())
    with pytest.raises(ConfigError, match=f"{section}.{key} = 'nope': expected one of .*lab-built"):
        cfg.from_dict({section: {key: "nope"}})


def test_fusion_methods_come_from_the_registry(monkeypatch):
    monkeypatch.setattr(fusion, "METHODS", (*fusion.METHODS, "lab-built"))
    assert cfg.from_dict({"fusion": {"method": "lab-built"}}).fusion.method == "lab-built"
    assert "lab-built" in cfg.reference()
    with pytest.raises(ConfigError, match="fusion.method = 'kalman': expected one of cnn"):
        cfg.from_dict({"fusion": {"method": "kalman"}})


def test_fusion_config_makes_every_method_with_its_parameters():
    c = cfg.from_dict({"fusion": {"window": 3, "vote_delay": 2, "lag": 4, "hysteresis": 0.9}})
    assert c.fusion.make().method == "hmm+voting" and c.fusion.delay_frames() == 3
    assert c.fusion.delay_frames("fixed-lag") == 4 and c.fusion.delay_frames("cnn+voting") == 2
    assert c.fusion.make("steady+hysteresis").hysteresis == 0.9


def test_preprocess_keys_are_checked(tmp_path):
    p = tmp_path / "c.toml"
    _refused(
        p, "[preprocess]\nmin_height_m = 2.0\nmax_height_m = 1.0\n", "preprocess.max_height_m = 1.0"
    )
    _refused(
        p, "[preprocess]\nbackend = 'gpu'\n", "preprocess.backend = 'gpu': expected one of numpy"
    )
