"""liblsl's own log never reaches the terminal: it goes to a file of walkcap's. In a fresh
process, as liblsl reads its configuration once per process."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pylsl")

ROOT = Path(__file__).resolve().parents[3]
CHILD = r"""
import sys
import time
from capture.labtools import lsl as L

pylsl = L.pylsl()
# a stream whose name liblsl quotes in its own lines (its threads are named after it)
info = pylsl.StreamInfo("brk[2J]0;owned", "EEG", 1, 100, "float32", "t-log-1")
outlet = pylsl.StreamOutlet(info)
(found,) = pylsl.resolve_byprop("source_id", "t-log-1", timeout=10)
inlet = pylsl.StreamInlet(found, recover=False)
inlet.open_stream(timeout=10)
outlet.push_sample([1.0])
inlet.pull_sample(timeout=10)
del outlet  # liblsl: "Stream transmission broke off ..." at error level
try:
    inlet.pull_sample(timeout=10)
except Exception:  # pylsl.util.LostError
    print("lost")
print("python's stderr still works", file=sys.stderr)
"""


@pytest.mark.subprocess
def test_liblsl_logs_into_its_file_and_nothing_onto_the_terminal(tmp_path):
    env = {**os.environ, "HOME": str(tmp_path), "PYTHONPATH": str(ROOT)}
    env.pop("LSLAPICFG", None)
    done = subprocess.run(
        [sys.executable, "-c", CHILD],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "lost" in done.stdout
    assert done.stderr.strip() == "python's stderr still works"  # no liblsl line at all
    log = (tmp_path / ".cache" / "walkcap" / "liblsl.log").read_text(errors="replace")
    assert "Logging to" in log and "broke off" in log  # liblsl's words went there
