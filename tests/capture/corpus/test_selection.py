"""The files a corpus command is given: files as they are, folders searched."""

import pytest

from capture.corpus.dataset import find_session_files
from capture.corpus.selection import recording_files
from capture.errors import CaptureError
from inference.errors import InferenceError


def test_folders_are_searched_and_files_kept_as_given(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    for name in ("a/t1.mcap", "a/b/t2.mcap", "a/.t3.mcap", "a/notes.txt", "a/s.npz"):
        (tmp_path / name).write_bytes(b"")
    given = tmp_path / "a" / "notes.txt"
    found = recording_files([tmp_path / "a", given, tmp_path / "a" / "t1.mcap"])
    assert found == [tmp_path / "a/b/t2.mcap", tmp_path / "a/t1.mcap", given]
    sessions = find_session_files([tmp_path / "a"])
    assert {p.name for p in sessions} == {"t1.mcap", "t2.mcap", ".t3.mcap", "s.npz"}


def test_a_folder_without_any_or_a_missing_path_is_one_clear_error(tmp_path):
    with pytest.raises(CaptureError, match="no .mcap recordings in this folder"):
        recording_files([tmp_path])
    with pytest.raises(InferenceError, match="no sessions"):
        find_session_files([tmp_path])
    with pytest.raises(CaptureError, match="nope: no such file or folder"):
        recording_files([tmp_path / "nope"])
