"""stderr says it once: a full disk is one line, not a log record and then the error; a
file that is no model is the error alone, without torch's warnings before it."""

from __future__ import annotations

import hashlib
import json
import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from inference.errors import InferenceError
from inference.model import BUNDLED_PATH, load_classifier
from tui import cli

ROOT = Path(__file__).resolve().parents[2]

FULL_DISK_RECORD = """
import sys
sys.path.insert(0, sys.argv[2])
from tests.recording_fixtures import disk_full_after
from capture.recording.chunks import TrackedFile
from tui import cli
TrackedFile.write = disk_full_after(400_000)
sys.exit(cli.main(["record", "--duration", "4", "--fps", "15", "--out", sys.argv[1]]))
"""


@pytest.mark.subprocess
def test_a_full_disk_is_said_once(tmp_path):
    """In a process of its own: the command's logging as a user gets it."""
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            FULL_DISK_RECORD,
            str(tmp_path),
            str(ROOT),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,  # this checkout's code, not an installed one
    )
    assert out.returncode == 1, out.stderr
    assert out.stderr.count("disk full") == 1, out.stderr
    (line,) = [line for line in out.stderr.splitlines() if "disk full" in line]
    assert line.startswith("walkcap record: error: ") and "Traceback" not in out.stderr


def test_a_log_line_is_one_line_without_a_timestamp(capsys):
    import logging

    cli._log_to_stderr("info", 0)
    logging.getLogger("capture.recording.writer").error("journal x: %s", "two\nlines")
    assert capsys.readouterr().err == "walkcap info: error: journal x: two lines\n"


def test_a_pickled_non_model_is_the_error_alone(tmp_path):
    path = tmp_path / "not_a_model.pt"
    path.write_bytes(pickle.dumps({"epochs": [1, 2, 3]}, protocol=4))
    meta = json.loads(BUNDLED_PATH.with_suffix(".json").read_text())
    meta["weights_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    path.with_suffix(".json").write_text(json.dumps(meta))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        with pytest.raises(InferenceError, match="not a state dict"):
            load_classifier(path)
    assert said == []
