"""A full disk while writing an output: nothing incomplete is left under a name that looks
whole, and the one-line error names the file. The limit is the process's own file size
limit (RLIMIT_FSIZE): the kernel refuses the write as it would on a full disk."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.recording_fixtures import write_recording

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("full") / "trial.mcap"
    write_recording(path, seconds=1.0)
    return path


def walkcap_with_a_full_disk(args, limit: int, home: Path):
    def full():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails instead (EFBIG)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "HOME": str(home), "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "tui.cli", *args],
        capture_output=True,
        text=True,
        env=env,
        preexec_fn=full,
        timeout=600,
    )


def one_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err and "internal error" not in err, err
    return lines[0]


@pytest.mark.subprocess
def test_recover_leaves_no_partial_file_and_names_the_output(recording, tmp_path):
    out = tmp_path / "out.mcap"
    done = walkcap_with_a_full_disk(["recover", str(recording), "-o", str(out)], 200_000, tmp_path)
    assert done.returncode == 1
    line = one_line(done.stderr)
    assert str(out) in line and "not written" in line
    assert sorted(p.name for p in tmp_path.iterdir() if p.is_file()) == []


@pytest.mark.subprocess
@pytest.mark.parametrize("fmt", ["csv", "mat"])
def test_export_leaves_no_truncated_table(recording, tmp_path, fmt):
    out = tmp_path / "tables"
    done = walkcap_with_a_full_disk(
        ["export", str(recording), "--format", fmt, "-o", str(out), "--quiet"], 20_000, tmp_path
    )
    assert done.returncode == 1
    line = one_line(done.stderr.replace("\r", "\n").splitlines()[-1])
    assert str(out) in line and "not written" in line
    assert not [p for p in out.iterdir() if "partial" in p.name]
    failed = Path(line.split("error: ", 1)[1].split(": not written")[0])
    assert failed.parent == out and not failed.exists()  # no truncated table under its name
