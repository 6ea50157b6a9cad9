import os

import pytest

# Never read a developer's ./walkcap.toml or $WALKCAP_CONFIG during tests.
os.environ.pop("WALKCAP_CONFIG", None)


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(autouse=True)
def _isolated_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    # `python -m tui.cli` in a subprocess runs this checkout's code, not an installed copy
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(filter(None, [ROOT, os.environ.get("PYTHONPATH")]))
    )
    yield
