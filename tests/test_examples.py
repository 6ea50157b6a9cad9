"""The scripts in examples/ run as a researcher runs them, each in its own Python, against
a tiny synthesized recording, score files of known accuracy and a local LSL outlet."""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import numpy as np
import pytest

from tui.cli import main

pytestmark = pytest.mark.subprocess

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
FRAMES = 12


def _example(name: str, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args], capture_output=True, text=True, timeout=240
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth")
    argv = ["synth", "--format", "recording", "--sessions", "1", "--frames", str(FRAMES)]
    assert main([*argv, "--seed", "3", "--out", str(out)]) == 0
    return out


def test_read_recording(recordings):
    (path,) = recordings.glob("*.mcap")
    out = _example("read_recording.py", str(path))
    assert out.startswith(f"{path.name}: ")
    assert re.search(rf"^  /camera/depth +{FRAMES} messages$", out, re.M)
    assert f"{FRAMES} classified frames" in out
    assert "fused decision = terrain on " in out
    keyed = re.findall(r"^  (LG|US|DS|UR|DR): (\d+) frames$", out, re.M)
    assert len(keyed) == 5 and sum(int(n) for _, n in keyed) == FRAMES  # every frame keyed


def test_export_tables(recordings, tmp_path):
    out = _example("export_tables.py", str(recordings), str(tmp_path / "tables"))
    assert f"frames: {FRAMES} rows" in out and "trials: 1 rows" in out
    written = sorted(p.name for p in (tmp_path / "tables").iterdir())
    tables = ["events", "frames", "gait", "imu", "labels", "trials"]
    assert written == [f"{name}.csv" for name in tables]
    assert len((tmp_path / "tables" / "frames.csv").read_text().splitlines()) == FRAMES + 1


def _scores(path: Path, correct: int, wrong: int) -> None:
    """A trial in LG whose scores pick LG on `correct` frames, then US on `wrong` ones."""
    rows = ["LG,US,DS,UR,DR,label"]
    rows += ["0.8,0.05,0.05,0.05,0.05,LG"] * correct + ["0.05,0.8,0.05,0.05,0.05,LG"] * wrong
    path.write_text("\n".join(rows) + "\n")


def test_eval_scores(tmp_path):
    _scores(tmp_path / "right.csv", 60, 0)
    _scores(tmp_path / "half.csv", 30, 30)
    out = _example("eval_scores.py", str(tmp_path / "right.csv"), str(tmp_path / "half.csv"))
    sd = 100 * np.std([1.0, 0.5], ddof=1)
    assert f"cnn          accuracy  75.00 % (SD {sd:.2f})" in out
    assert out.count("accuracy") == 4  # the paper's four methods
    assert f"{tmp_path / 'right.csv'} cnn 100.0" in out
    assert f"{tmp_path / 'half.csv'} cnn 50.0" in out


def test_listen_lsl():
    pytest.importorskip("pylsl")
    from capture.labtools.lsl import LslOutlets
    from devices.clock import now_ns

    name = f"wc-example-{uuid.uuid4().hex[:8]}"
    outlets = LslOutlets(imu_rate_hz=100, camera_fps=15, name=name)
    stop = threading.Event()

    def send() -> None:  # a session's classifier output: CNN says US, the fusion DS
        k = 0
        while not stop.wait(0.02):
            fused = {"frame_index": k, "decision": "DS"}
            outlets.write_inference(k, now_ns(), now_ns(), [0.1, 0.6, 0.1, 0.1, 0.1], fused)
            k += 1

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        out = _example("listen_lsl.py", "--name", name, "--count", "3", "--timeout", "60")
    finally:
        stop.set()
        sender.join()
        outlets.close()
    assert out.splitlines()[0].startswith("channels: frame_index, p_LG, p_US")
    decisions = out.splitlines()[1:]
    assert len(decisions) == 3
    assert all(line.endswith("CNN US, fused DS") for line in decisions), out
