"""The recordings folder and the checkout: `walkcap check` warns when `git clean -xfd`
would delete the recordings, and one command points them elsewhere."""

import tomllib

import pytest

from capture import config as cfg
from capture.live import preflight
from tui import cli


@pytest.fixture
def checkout(tmp_path):
    repo = tmp_path / "walkcap"
    (repo / ".git").mkdir(parents=True)
    return repo


def test_a_folder_in_a_git_work_tree_is_a_warning_that_says_what_to_do(checkout, tmp_path):
    item = preflight.folder_item(checkout / "recordings")
    assert item.ok  # a warning: it does not block
    assert "git clean -xfd" in item.warning and str(checkout) in item.warning
    assert "walkcap config --set session.recordings=" in item.warning
    assert item.details["git_work_tree"] == str(checkout)
    worktree = tmp_path / "wt"
    worktree.mkdir()
    (worktree / ".git").write_text("gitdir: /elsewhere/.git/worktrees/wt\n")  # git worktree
    assert "git clean" in preflight.folder_item(worktree / "deep" / "recordings").warning
    data = tmp_path / "data"
    assert preflight.folder_item(data).warning == ""


def test_check_prints_the_warning_line(checkout, tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")  # the devices never start: the folder is checked anyway
    cli.main(["check", "--model", str(bad), "--out", str(checkout / "recordings")])
    out = capsys.readouterr().out
    (line,) = [x for x in out.splitlines() if "git clean -xfd" in x]
    assert line.strip().startswith("warning: inside the git work tree")


def test_config_set_points_the_recordings_at_a_data_disk(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "walkcap.toml"
    path.write_text(
        '# our lab\n[camera]\nfps = 15.0  # the lab\'s mode\n\n[session]\noperator = "RA1"\n'
    )
    code = cli.main(["config", "--set", "session.recordings=/mnt/data/walkcap"])
    assert code == 0 and "set session.recordings=/mnt/data/walkcap" in capsys.readouterr().out
    text = path.read_text()
    assert text.startswith("# our lab\n") and "fps = 15.0  # the lab's mode" in text
    loaded = cfg.load(path)
    assert loaded.session.recordings == "/mnt/data/walkcap" and loaded.session.operator == "RA1"
    cli.main(["config", "--set", "session.recordings=/mnt/other", "--set", "camera.fps=10"])
    loaded = cfg.load(path)
    assert (loaded.session.recordings, loaded.camera.fps) == ("/mnt/other", 10.0)
    assert tomllib.loads(path.read_text())["session"] == {
        "operator": "RA1",
        "recordings": "/mnt/other",
    }


def test_config_set_refuses_a_bad_value_and_leaves_the_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "walkcap.toml"
    path.write_text("[camera]\nfps = 15.0\n")
    for bad in ("camera.fps=fast", "camera.fps=0", "camera.nokey=1", "recordings=/x"):
        assert cli.main(["config", "--set", bad]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err  # one line
    assert path.read_text() == "[camera]\nfps = 15.0\n"


def test_config_set_makes_the_file_when_there_is_none(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["config", "--set", "session.recordings=/mnt/data"]) == 0
    assert cfg.load(tmp_path / "walkcap.toml").session.recordings == "/mnt/data"


async def test_the_ui_says_it_when_its_pre_flight_finds_the_checkout(checkout):
    from capture.config import Config
    from capture.live.preflight import PreflightReport
    from capture.live.trials import SubjectInfo
    from tests.tui.screens import SIZE, open_live
    from tests.tui_fake_session import FakeSession
    from tests.waiting import wait_for_app
    from tui.app import WalkcapApp
    from tui.session_screen import save_last_session

    save_last_session(SubjectInfo(subject="S05", trial=1))
    item = preflight.folder_item(checkout / "recordings")
    app = WalkcapApp(
        Config(), session=FakeSession(), preflight=lambda session: PreflightReport([item])
    )
    async with app.run_test(size=SIZE) as pilot:
        await open_live(pilot)
        await wait_for_app(pilot, lambda: app.preflight_state == "ok")
        await wait_for_app(pilot, lambda: any("git clean" in n.text for n in app.notices))
        (notice,) = [n for n in app.notices if "git clean" in n.text]
        assert notice.severity == "warning" and "git checkout" in notice.short
