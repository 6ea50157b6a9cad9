"""Corpus jobs on a Ray cluster give what the single-machine path gives.

One local cluster (2 CPUs) for the module: the commands' `--cluster local` joins it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

from capture.corpus import cluster, jobs  # noqa: E402
from tests.recording_fixtures import decoded_messages  # noqa: E402
from tui.cli import main  # noqa: E402


@pytest.fixture(scope="module", autouse=True)
def local_cluster():
    # this module's functions travel by value: the workers need not import tests/
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with cluster.connect("local", num_cpus=2):
        yield


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_synth_dataset_files_are_byte_identical(tmp_path, capsys):
    args = ["synth", "--sessions", "3", "--frames", "4"]
    assert _run(capsys, *args, "--out", str(tmp_path / "one"))[0] == 0
    assert _run(capsys, *args, "--out", str(tmp_path / "ray"), "--cluster", "local")[0] == 0
    one = sorted((tmp_path / "one").iterdir())
    assert [p.name for p in one] == sorted(p.name for p in (tmp_path / "ray").iterdir())
    assert len(one) == 3
    for p in one:
        assert p.read_bytes() == (tmp_path / "ray" / p.name).read_bytes()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Synthesized recordings, on this process and on the cluster."""
    base = tmp_path_factory.mktemp("recordings")
    args = ["synth", "--format", "recording", "--sessions", "2", "--frames", "20"]
    assert main([*args, "--out", str(base / "one")]) == 0
    assert main([*args, "--out", str(base / "ray"), "--cluster", "local"]) == 0
    return base


def test_synth_recordings_hold_the_same_messages(recordings):
    one = sorted((recordings / "one").glob("*.mcap"))
    assert len(one) == 2
    for p in one:
        ray_copy = recordings / "ray" / p.name
        assert decoded_messages(p, relative=True) == decoded_messages(ray_copy, relative=True)


def test_replay_outputs_equal_and_eval_tables_equal(recordings, tmp_path, capsys):
    files = [str(p) for p in sorted((recordings / "one").glob("*.mcap"))]
    code, out_one, _ = _run(capsys, "replay", *files, "-o", str(tmp_path / "one"))
    assert code == 0
    code, out_ray, _ = _run(
        capsys, "replay", *files, "-o", str(tmp_path / "ray"), "--cluster", "local"
    )
    assert code == 0
    assert [Path(p).name for p in out_one.split()] == [Path(p).name for p in out_ray.split()]
    for p in out_one.split():
        assert decoded_messages(Path(p)) == decoded_messages(tmp_path / "ray" / Path(p).name)

    code, table_one, _ = _run(capsys, "eval", "recordings", *files, "--json")
    assert code == 0
    code, table_ray, _ = _run(capsys, "eval", "recordings", *files, "--json", "--cluster", "local")
    assert code == 0
    assert table_one == table_ray and '"files"' in table_one


def test_export_tables_equal(recordings, tmp_path, capsys):
    base = ["export", str(recordings / "one"), "--format", "csv", "--quiet"]
    assert _run(capsys, *base, "-o", str(tmp_path / "one"))[0] == 0
    assert _run(capsys, *base, "-o", str(tmp_path / "ray"), "--cluster", "local")[0] == 0
    one = sorted((tmp_path / "one").glob("*.csv"))
    assert len(one) >= 4
    for p in one:
        assert p.read_bytes() == (tmp_path / "ray" / p.name).read_bytes(), p.name


def test_a_failed_trial_is_named_and_the_others_are_written(recordings, tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not a recording")
    good = sorted((recordings / "one").glob("*.mcap"))[0]
    code, out, err = _run(
        capsys, "replay", str(good), str(bad), "-o", str(tmp_path / "out"), "--cluster", "local"
    )
    assert code == 1
    assert "bad.mcap: failed:" in err and "not an MCAP recording" in err
    assert "1 of 2 recordings failed" in err
    assert "Traceback" not in err
    assert (tmp_path / "out" / f"{good.stem}.replay.mcap").exists()
    assert out.split() == [str(tmp_path / "out" / f"{good.stem}.replay.mcap")]


def _flaky(marker: str) -> str:
    if not os.path.exists(marker):
        Path(marker).write_text("tried")
        raise RuntimeError("lost on the first attempt")
    return "second attempt"


def _broken(name: str) -> str:
    raise ValueError(f"{name} is broken")


def test_a_task_is_retried_once_then_reported(tmp_path, capsys):
    marker = str(tmp_path / "marker")
    here = jobs.Cluster("local")
    assert jobs.run([jobs.Task("flaky", _flaky, (marker,))], here) == ["second attempt"]
    tasks = [jobs.Task("ok", _flaky, (marker,)), jobs.Task("t07", _broken, ("t07",))]
    said = []
    with pytest.raises(cluster.ClusterError, match=r"1 of 2 tasks failed .*: t07") as e:
        jobs.run(tasks, here, on_result=lambda i, r: said.append((i, r)))
    assert e.value.results == ["second attempt", None]
    assert said == [(0, "second attempt")]
    assert "t07: failed: ValueError: t07 is broken" in capsys.readouterr().err


def test_training_workers_keep_enough_images_per_batch():
    assert cluster.training_workers(64, cpus=2) == 2
    assert cluster.training_workers(64, cpus=32) == 4
    assert cluster.training_workers(64, cpus=2, wanted=1) == 1
    with pytest.raises(cluster.ClusterError, match="at most 2"):
        cluster.training_workers(32, cpus=8, wanted=3)


def test_train_on_the_cluster_with_ddp(tmp_path, capsys):
    """Two DDP workers train, validate and stop together; rank 0's model is written."""
    data = tmp_path / "data"
    assert _run(capsys, "synth", "--out", str(data), "--sessions", "6", "--frames", "40")[0] == 0
    out = tmp_path / "m.pt"
    code, text, err = _run(
        capsys,
        "train",
        "--data",
        str(data),
        "--out",
        str(out),
        "--epochs",
        "2",
        "--samples-per-epoch",
        "96",
        "--batch-size",
        "32",
        "--quiet",
        "--cluster",
        "local",
        "--workers",
        "2",
    )
    assert code == 0, err
    assert "training on 2 worker(s)" in err
    assert out.exists() and out.with_suffix(".json").exists()
    import json

    meta = json.loads(out.with_suffix(".json").read_text())
    history = meta["training"]["history"]
    assert len(history) == 2
    assert all(0 <= h["val_accuracy"] <= 1 and h["train_loss"] > 0 for h in history)
    assert "test sessions" in text


def test_an_address_where_no_cluster_answers_is_one_line(capsys):
    import socket

    with socket.socket() as free:  # a port nobody listens on
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    with pytest.raises(cluster.ClusterError, match="no Ray cluster answers at 127.0.0.1"):
        cluster._reachable(f"127.0.0.1:{port}")


@pytest.fixture(scope="module")
def running_head(tmp_path_factory):
    """A cluster started as the README says (`ray start --head`), with token
    authentication; its token in a home of its own. Yields (address, home)."""
    import re
    import signal
    import socket
    import subprocess
    import time

    home = tmp_path_factory.mktemp("head-home")
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    env = {**os.environ, "HOME": str(home), "RAY_AUTH_MODE": "token"}
    env.pop("RAY_ADDRESS", None)
    ray_cli = str(Path(sys.executable).parent / "ray")
    generate = [ray_cli, "get-auth-token", "--generate"]
    subprocess.run(generate, env=env, capture_output=True, check=True)
    head = subprocess.Popen(
        [
            ray_cli,
            "start",
            "--head",
            "--block",
            f"--port={port}",
            "--num-cpus=1",
            "--include-dashboard=false",
            "--disable-usage-stats",
        ],  # fmt: skip
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    address, deadline = None, time.monotonic() + 60
    while address is None and time.monotonic() < deadline and head.poll() is None:
        line = head.stdout.readline()
        found = re.search(r"--address='([^']+)'", line)
        address = found.group(1) if found else None
    if address is None:
        head.kill()
        pytest.fail(f"ray start --head did not give an address: {head.stdout.read()[-500:]}")
    yield address, home
    os.killpg(head.pid, signal.SIGTERM)
    try:
        head.wait(timeout=3)
    except subprocess.TimeoutExpired:
        pass
    try:  # the head's processes, raylet's workers included, share its session
        os.killpg(head.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def _walkcap_at(address: str, out: Path, **env: str | None) -> tuple[int, str, float]:
    import subprocess
    import time

    t = time.monotonic()
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "tui.cli",
            "synth",
            "--out",
            str(out),
            "--sessions",
            "2",
            "--frames",
            "3",
            "--cluster",
            address,
        ],  # fmt: skip
        # None: unset (a local cluster of this process sets RAY_AUTH_MODE in its environment)
        env={k: v for k, v in {**os.environ, **env}.items() if v is not None},
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[3],
    )
    return done.returncode, done.stderr, time.monotonic() - t


@pytest.mark.subprocess
def test_a_running_cluster_is_joined_by_its_address(running_head, tmp_path):
    address, home = running_head
    rc, err, _ = _walkcap_at(address, tmp_path / "out", HOME=str(home), RAY_AUTH_MODE="token")
    assert rc == 0, err
    assert len(list((tmp_path / "out").glob("*.npz"))) == 2


@pytest.mark.subprocess
def test_a_cluster_that_wants_a_token_is_one_line_soon(running_head, tmp_path):
    address, _ = running_head
    elsewhere = tmp_path / "home"  # a machine without the cluster's token
    elsewhere.mkdir()
    rc, err, seconds = _walkcap_at(
        address,
        tmp_path / "out",
        HOME=str(elsewhere),
        RAY_AUTH_MODE=None,
        RAY_gcs_server_port_wait_time_s="2",
    )
    lines = err.strip().splitlines()
    assert rc == 1 and len(lines) == 1, err
    assert "uses token authentication: set RAY_AUTH_MODE=token" in lines[0]
    assert seconds < 30
    rc, err, _ = _walkcap_at(address, tmp_path / "out", HOME=str(elsewhere), RAY_AUTH_MODE="token")
    assert rc == 1 and "no token is: give the cluster's token in RAY_AUTH_TOKEN" in err
    assert not list((tmp_path / "out").glob("*.npz"))
