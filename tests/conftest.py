import os

import pytest

# Never read a developer's ./walkcap.toml or $WALKCAP_CONFIG during tests.
os.environ.pop("WALKCAP_CONFIG", None)


@pytest.fixture(autouse=True)
def _isolated_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    yield
