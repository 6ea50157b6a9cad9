"""Fixtures shared by the recording tests."""

import pytest

from tests.recording_fixtures import write_recording


@pytest.fixture(scope="session")
def recording(tmp_path_factory):
    """A 2 s recording by the recorder (tests.recording_fixtures), read and never changed."""
    path = tmp_path_factory.mktemp("recording") / "S07_indoor_t03.mcap"
    write_recording(path, seconds=2.0)
    return path
