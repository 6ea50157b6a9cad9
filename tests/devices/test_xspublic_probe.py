"""Xsens' own host library (xspublic, xscontroller) drives `walkcap imu emulate`.

The vendor source is not part of walkcap: XSPUBLIC_DIR names it (`.ci/run` sets it when
../shared/vendor/xspublic exists). It is copied to a cache folder keyed by a hash of the
source, built there once per machine with its own Makefile, and walkcap's probe
(tests/devices/vendor_probe/probe.cpp) is linked against it. The probe opens the emulator by its
port name, reads the identity, configures outputs as Xsens' example does, measures until it
has its packets and checks the packet counters, for MTi-1, MTi-3 and MTi-630.
"""

import fcntl
import hashlib
import os
import re
import select
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(1200)

HERE = Path(__file__).resolve().parent
PROBE_SOURCE = HERE / "vendor_probe" / "probe.cpp"
# Read at import, before the tests' private HOME: the build is kept once per machine.
CACHE_ROOT = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "walkcap-test"
SAMPLES = 300  # three seconds at 100 Hz
PROBE_TIMEOUT_S = 120.0  # generous: the probe stops as soon as it has its samples


def source_hash(root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        if path.is_file():
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def build_xspublic(source: Path) -> Path:
    """The built library for this source: built here the first time, reused after."""
    CACHE_ROOT.mkdir(parents=True, exist_ok=True)
    built = CACHE_ROOT / f"xspublic-{source_hash(source)}"
    with open(CACHE_ROOT / f"{built.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one build at a time on this machine
        if (built / "xscontroller" / "libxscontroller.a").exists():
            return built
        work = CACHE_ROOT / f"{built.name}.build-{os.getpid()}"
        shutil.rmtree(work, ignore_errors=True)
        shutil.copytree(source, work)  # it writes its objects next to its sources
        for path in [work, *work.rglob("*")]:  # the source may be read-only; the copy is not
            path.chmod(path.stat().st_mode | stat.S_IWUSR)
        jobs = str(max(1, min(2, os.cpu_count() or 1)))
        out = subprocess.run(["make", "-C", str(work), f"-j{jobs}"], capture_output=True, text=True)
        if out.returncode != 0:
            shutil.rmtree(work, ignore_errors=True)
            pytest.fail(f"building xspublic failed:\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}")
        shutil.rmtree(built, ignore_errors=True)
        work.rename(built)
    return built


def build_probe(library: Path) -> Path:
    key = hashlib.sha256(PROBE_SOURCE.read_bytes()).hexdigest()[:12]
    probe = library / f"walkcap-probe-{key}"
    if probe.exists():
        return probe
    partial = probe.with_name(f"{probe.name}.{os.getpid()}")
    command = [
        "g++",
        "-std=c++11",
        "-O1",
        f"-I{library}",
        "-include",
        str(library / "xscontroller" / "xscontrollerconfig.h"),
        str(PROBE_SOURCE),
        "-o",
        str(partial),
        f"-L{library / 'xscontroller'}",
        f"-L{library / 'xscommon'}",
        f"-L{library / 'xstypes'}",
        "-lxscontroller",
        "-lxscommon",
        "-lxstypes",
        "-lpthread",
        "-ldl",
        "-lrt",
    ]
    out = subprocess.run(command, capture_output=True, text=True)
    if out.returncode != 0:
        pytest.fail(f"building the probe failed:\n{out.stderr[-3000:]}")
    partial.rename(probe)
    return probe


@pytest.fixture(scope="module")
def probe() -> Path:
    source = os.environ.get("XSPUBLIC_DIR")
    if not source:
        pytest.skip(
            "XSPUBLIC_DIR is not set: Xsens' xspublic source is needed to drive the emulator "
            "with the vendor's library (.ci/run sets it from ../shared/vendor/xspublic)"
        )
    if not (Path(source) / "xscontroller").is_dir():
        pytest.skip(f"XSPUBLIC_DIR={source} holds no xspublic source (no xscontroller/)")
    missing = [tool for tool in ("g++", "make") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"building xspublic needs {' and '.join(missing)}, not on this machine")
    return build_probe(build_xspublic(Path(source)))


def first_line(proc: subprocess.Popen, timeout: float) -> str:
    """The first line the process prints, read from the pipe itself (no Python buffer
    between select and the bytes)."""
    deadline = time.monotonic() + timeout
    fd = proc.stdout.fileno()
    data = b""
    while b"\n" not in data and time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.5)
        if ready:
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            data += chunk
    return data.split(b"\n")[0].decode().strip()


@pytest.mark.realtime
@pytest.mark.subprocess
@pytest.mark.parametrize("model", ["MTi-1", "MTi-3", "MTi-630"])
def test_xsens_library_opens_configures_and_streams_from_the_emulator(probe, model, tmp_path):
    log = tmp_path / "emulate.log"
    with open(log, "wb") as err:
        emulator = subprocess.Popen(
            [sys.executable, "-m", "tui.cli", "imu", "emulate", "--model", model]
            + ["--rate", "100", "--baudrate", "115200", "--seconds", "600"],
            stdout=subprocess.PIPE,
            stderr=err,
        )
    try:
        port = first_line(emulator, 60.0)
        assert port, f"walkcap imu emulate printed no port: {log.read_text()[-2000:]}"
        out = subprocess.run(
            [str(probe), port, "115200", str(SAMPLES), str(PROBE_TIMEOUT_S), "100"],
            capture_output=True,
            text=True,
            timeout=PROBE_TIMEOUT_S + 120,
        )
    finally:
        emulator.send_signal(signal.SIGINT)  # it removes its port folder on the way out
        try:
            emulator.wait(30)
        except subprocess.TimeoutExpired:
            emulator.kill()
    report = out.stdout
    assert out.returncode == 0, f"probe failed:\n{report}\n{out.stderr[-2000:]}"
    facts = dict(line.split(" ", 1) for line in report.splitlines() if " " in line)
    assert facts["product_code"] == {"MTi-1": "MTi-1-8A7G6", "MTi-3": "MTi-3-8A7G6"}.get(
        model, model
    )
    assert int(facts["packets"]) >= SAMPLES and int(facts["missing"]) == 0
    assert facts["result"] == "ok"
    # The library's view of the family: an IMU-only MTi-1, AHRS otherwise.
    assert ("imu 1" in report) == (model == "MTi-1")
    assert ("mti6x0 1" in report) == (model == "MTi-630")
    granted = dict(re.findall(r"^output (0x[0-9A-F]{4}) (\d+)$", report, re.M))
    assert granted["0x1020"] == granted["0x1060"] == granted["0xE020"] == "65535"
