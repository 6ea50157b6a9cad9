"""What README.md and docs/recordings.md say the program does, checked against the program:
the exit codes of usage and user errors (README), the name `recover` writes and the time
columns of every exported table (docs/recordings.md)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from capture.corpus import export
from tests.recording_fixtures import write_recording
from tui.cli import main

ROOT = Path(__file__).parent.parent
README = (ROOT / "README.md").read_text()
RECORDINGS = (ROOT / "docs" / "recordings.md").read_text()


def flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def walkcap(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tui.cli", *argv], capture_output=True, text=True, timeout=120
    )


def test_recover_writes_the_file_the_docs_name(tmp_path):
    (template,) = re.findall(r"`walkcap recover FILE` writes `([^`]+)`", flat(RECORDINGS))
    path = tmp_path / "S01_indoor_t02_20261122-102000.mcap"
    write_recording(path, seconds=0.5)
    assert main(["recover", str(path)]) == 0
    named = tmp_path / template.replace("<name>", path.stem).replace("FILE", path.name)
    assert named.is_file()
    assert sorted(p.name for p in tmp_path.glob("*.mcap")) == sorted({path.name, named.name})


@pytest.mark.slow
@pytest.mark.subprocess
def test_usage_errors_and_user_errors_exit_as_the_readme_says(tmp_path):
    text = flat(README)
    usage = re.search(r"A usage error \(.*?\) prints one line on stderr and exits (\d)", text)
    other = re.search(r"any other user error \(.*?\) prints one line and exits (\d)", text)
    assert usage and other, "README states the exit codes of usage and user errors"
    for argv in (["info", "--no-such-flag", "x.mcap"], ["record", "--trial", "x"], ["nope"]):
        done = walkcap(*argv)
        assert done.returncode == int(usage.group(1)), (argv, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1
    done = walkcap("info", str(tmp_path / "missing.mcap"))
    assert done.returncode == int(other.group(1)) and "no such file" in done.stderr


def test_every_exported_table_has_the_time_columns_the_docs_list(tmp_path):
    text = flat(RECORDINGS)
    claim = re.search(r"exported (.*?) tables? ha(?:ve|s) `time_ns`", text)
    assert claim
    named = re.findall(r"`(\w+)`", claim.group(1))
    path = tmp_path / "trial.mcap"
    write_recording(path, seconds=0.5)
    tables = export.tables(path)
    for name in named or export.TABLES:  # "every exported table": all of them
        assert {"time_ns", "unix_time_ns", "time_s"} <= set(tables[name].columns), name
    trials = re.search(r"`trials` has the file's (.*?)\.", text)
    assert trials, "docs/recordings.md says which times `trials` has"
    columns = re.findall(r"`(\w+)`", trials.group(1))
    assert columns and set(columns) <= set(tables["trials"].columns)
    assert int(tables["trials"]["end_time_ns"][0]) > int(tables["trials"]["start_time_ns"][0])
