"""Bad input is one clear line and exit 1 or 2, never an internal error or a hang, and an
output path that names a device, a pipe or a folder is refused before anything is written
(renaming a new file over /dev/null replaces the device node)."""

from __future__ import annotations

import json
import os
import shutil
import stat

import pytest

from inference.model import BUNDLED_PATH, metadata_path
from tests.recording_fixtures import write_recording
from tui import cli


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("bad_input") / "trial.mcap"
    write_recording(path, seconds=1.0)
    return path


def one_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err and "internal error" not in err, err
    return lines[0]


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe"
    os.mkfifo(path)
    return path


def still_a_fifo(path) -> bool:
    return stat.S_ISFIFO(os.stat(path).st_mode)


def test_recover_refuses_to_rename_over_a_device_or_a_pipe(recording, fifo, capsys):
    assert cli.main(["recover", str(recording), "-o", str(fifo), "--force"]) == 1
    assert "not a regular file" in one_line(capsys.readouterr().err)
    assert still_a_fifo(fifo) and not list(fifo.parent.glob("*.partial"))


def test_recover_refuses_an_empty_output_path(recording, capsys):
    assert cli.main(["recover", str(recording), "-o", ""]) == 1
    assert "empty" in one_line(capsys.readouterr().err)


def test_train_and_the_dataset_and_config_writers_refuse_a_pipe(fifo, tmp_path):
    import numpy as np

    from capture.config import Config, save
    from devices.files import NotARegularFile
    from inference.dataset import LabeledSession, write_session
    from inference.model import TerrainCNN, save_model

    with pytest.raises(NotARegularFile):
        save_model(TerrainCNN(hidden=4), fifo)
    session = LabeledSession("s", np.zeros((1, 100, 100), np.uint8), np.zeros(1, int))
    with pytest.raises(NotARegularFile):
        write_session(fifo, session)
    with pytest.raises(NotARegularFile):
        save(Config(), fifo)
    with pytest.raises(NotARegularFile):
        save(Config(), tmp_path)  # a folder
    assert still_a_fifo(fifo)


def test_the_corrected_copy_refuses_a_pipe(recording, fifo):
    from devices.files import NotARegularFile
    from tui.replay import write_corrected

    with pytest.raises(NotARegularFile):
        write_corrected(recording, fifo, [], [])
    assert still_a_fifo(fifo)


@pytest.mark.parametrize(
    "argv",
    [
        ["record", "--trial", "99999999999999999999", "--duration", "1"],
        ["synth", "--seed", "-1", "--out", "OUT"],
        ["record", "--seed", "-1", "--duration", "1"],
    ],
)
def test_out_of_range_numbers_are_usage_errors(tmp_path, capsys, argv):
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    with pytest.raises(SystemExit) as exit:
        cli.main(argv)
    assert exit.value.code == 2
    one_line(capsys.readouterr().err)
    assert not list(tmp_path.rglob("*.mcap"))


@pytest.mark.parametrize(
    "toml, words",
    [
        ('[session]\nrecordings = "a\\u0000b"\n', "NUL"),
        ("x = " + "[" * 2000 + "]" * 2000 + "\n", "nested"),
        ("[simulator]\nspeed_mps = 1e-300\n", "speed_mps"),
        ("[simulator]\nseed = -1\n", "seed"),
    ],
    ids=["nul", "deep", "slow", "seed"],
)
def test_configuration_values_that_cannot_work_are_one_line(tmp_path, capsys, toml, words):
    path = tmp_path / "walkcap.toml"
    path.write_text(toml)
    out = tmp_path / "rec"
    assert cli.main(["record", "--config", str(path), "--duration", "2", "-o", str(out)]) == 1
    assert words in one_line(capsys.readouterr().err)
    assert not out.exists() or not list(out.iterdir())


@pytest.mark.parametrize(
    "architecture", [{"hidden": 1_000_000}, {"hidden": True}, "x", {"hidden": 0}]
)
def test_model_metadata_out_of_range_is_one_line(tmp_path, capsys, architecture):
    weights = tmp_path / "m.pt"
    shutil.copy(BUNDLED_PATH, weights)
    meta = json.loads(metadata_path(BUNDLED_PATH).read_text())
    meta["architecture"] = architecture
    metadata_path(weights).write_text(json.dumps(meta))
    assert cli.main(["eval", "model", "--model", str(weights)]) == 1
    assert "architecture" in one_line(capsys.readouterr().err)


def test_a_model_path_that_is_a_device_says_so(capsys):
    assert cli.main(["eval", "model", "--model", "/dev/zero"]) == 1
    assert "not a regular file" in one_line(capsys.readouterr().err)
