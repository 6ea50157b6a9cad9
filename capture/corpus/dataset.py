"""Labelled sessions from files and from the simulator, for training and evaluation.

Reading: `read_sessions` takes files and folders of synthesized sessions (.npz, the format
of inference.dataset) and of recordings (.mcap, the recorded /camera/binary_image labelled
with the operator's mode in force at each frame; `labeled_session`).

Synthesizing: `render_synth_session` walks one simulated course and preprocesses every
frame as the live pipeline does; `synth_dataset` writes many, one .npz each.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from capture.corpus import jobs
from capture.corpus.selection import given_files
from capture.errors import CaptureError
from capture.recording import labels as L
from capture.recording import topics as T
from capture.recording.reader import open_recording
from devices.config import MountingConfig, SimulatorConfig
from devices.frames import MODES
from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.simulator import Simulator, make_course
from devices.simulator.simulator import WALKER_KEYS, draw_walker
from inference.config import PreprocessConfig
from inference.dataset import LabeledSession, read_session, write_session
from inference.errors import InferenceError
from inference.preprocess import metadata as preprocess_metadata
from inference.preprocess import preprocess_frame


def labeled_session(path: str | os.PathLike, reference: str = "terrain"):
    """The recording as a training session (inference.dataset.LabeledSession): every
    classifier input image, labelled with what it shows (`reference` "terrain": the
    simulator's truth where the recording has it, else the labels), the operator's mode at
    its time ("labels"), or the simulator's truth ("truth"); -1 where there is none."""
    rec = open_recording(path)
    images: dict[int, np.ndarray] = {}
    times: dict[int, int] = {}
    for m in rec.messages([T.BINARY_IMAGE]):
        images[m.sequence] = (np.asarray(m.data) > 0).astype(np.uint8)
        times[m.sequence] = m.publish_time_ns
    if not images:
        raise CaptureError(f"{rec.path}: no classifier images (/camera/binary_image) to train on")
    index = sorted(images)
    t = np.array([times[i] for i in index], dtype=np.int64)
    if reference == "terrain":
        reference = "truth" if T.TRUTH in rec.topics else "labels"
    if reference == "truth":
        truth = {
            int(m.data["frame_index"]): L.mode_index(m.data.get("mode"))
            for m in rec.messages([T.TRUTH])
        }
        labels = np.array([truth.get(i, -1) for i in index], dtype=np.int64)
    else:
        changes = [L.change_from_message(m.data) for m in rec.messages([T.LABELS])]
        labels = L.labels_at(t, L.effective_changes(changes)).astype(np.int64)
    session = rec.meta.session
    return LabeledSession(
        name=Path(rec.path).stem,
        images=np.stack([images[i] for i in index]),
        labels=labels,
        preset=session.condition if session.has("condition") else "",
        source="recording",
        meta={"path": str(rec.path), "session": session.to_dict(), "reference": reference},
    )


def _read_recording(path: Path) -> LabeledSession:
    """A walkcap recording: its classifier inputs, labelled by the operator's mode."""
    try:
        return labeled_session(path)
    except CaptureError as e:
        raise InferenceError(str(e)) from None


# Readers by file suffix.
READERS: dict[str, Callable[[Path], LabeledSession]] = {
    ".npz": read_session,
    ".mcap": _read_recording,
}


def find_session_files(paths: list[str | os.PathLike]) -> list[Path]:
    """Files of sessions: the given files, and every known file in the given folders."""
    return given_files(paths, _is_session, "sessions (.npz or .mcap)", InferenceError)


def _is_session(f: Path) -> bool:
    return f.suffix.lower() in READERS and ".tmp" not in f.name


def select_session_files(
    paths: list[str | os.PathLike], replays: bool = False
) -> tuple[list[Path], list[str]]:
    """Like find_session_files, with one recording per trial (capture.corpus.selection.select): a
    trial's derived copies never stand beside it (one trial in both training and test).
    Returns the files and the lines that say which recordings were left out, and why."""
    from capture.corpus.selection import select

    files = find_session_files(paths)
    recordings = [f for f in files if f.suffix.lower() == ".mcap"]
    if not recordings:
        return files, []
    corpus = select(recordings, replays=replays)
    chosen = set(corpus.files)
    return [f for f in files if f.suffix.lower() != ".mcap" or f in chosen], corpus.report_lines()


def read_sessions(paths: list[str | os.PathLike]) -> list[LabeledSession]:
    """Every session under `paths` (files or folders), whatever its source."""
    sessions = []
    for f in find_session_files(paths):
        reader = READERS.get(f.suffix.lower())
        if reader is None:
            raise InferenceError(f"{f}: unknown session file type {f.suffix!r}")
        sessions.append(reader(f))
    return sessions


@dataclass(frozen=True)
class SynthSettings:
    """How a synthesized session is made, beyond its preset and seed."""

    fps: float = 15.0  # the paper's camera rate
    # The attitude filter's error: the MTi 1-series' roll/pitch accuracy as a slowly
    # drifting error (devices.orientation_error).
    imu_error: OrientationErrorModel = OrientationErrorModel()
    # Per session: the mounting's pitch error left after `walkcap calibrate` (1 sigma; the
    # strap settling).
    mounting_error_deg: float = 0.5
    vary_walker: bool = True  # draw speed, cadence, camera height and tilt per session
    max_frames: int = 0  # stop a session after this many frames (0: the whole walk)


def session_seed(base_seed: int, index: int) -> int:
    return base_seed + index


def session_plan(count: int, preset: str, base_seed: int) -> list[tuple[str, int]]:
    """(preset, seed) of each session; "both" alternates indoor and outdoor."""
    if preset not in ("indoor", "outdoor", "both"):
        raise InferenceError(f"unknown preset {preset!r} (indoor, outdoor or both)")
    presets = ("indoor", "outdoor") if preset == "both" else (preset,)
    return [(presets[i % len(presets)], session_seed(base_seed, i)) for i in range(count)]


def session_walker(
    seed: int, vary: bool, simulator_config, mounting_error_deg: float
) -> tuple[dict, float, np.random.Generator]:
    """A synthesized session's walker (drawn for the seed, or the configured one), the
    camera pitch the operator would calibrate for it (its tilt plus `mounting_error_deg`,
    1 sigma: the strap settling), and the session's random generator after both draws:
    the same seed gives the same walker as a training session and as a recording."""
    rng = np.random.default_rng([seed, 7919])
    if vary:
        walker = draw_walker(rng)
    else:
        walker = {k: getattr(simulator_config, k) for k in WALKER_KEYS}
    pitch = walker["camera_tilt_deg"] + float(rng.normal(0.0, mounting_error_deg))
    return walker, pitch, rng


def render_synth_session(
    preset: str,
    seed: int,
    params=None,
    settings: SynthSettings = SynthSettings(),
    simulator_config=None,
    progress: Callable[[int], None] | None = None,
    mounting=None,
) -> tuple[LabeledSession, dict]:
    """Walk one simulated course and preprocess every frame as the live pipeline does.

    The IMU orientation is the simulator's thigh orientation with the attitude filter's
    slowly drifting error; the preprocessing uses the mounting the operator would have
    calibrated (true tilt plus a small error; roll and yaw those of `mounting`, a
    MountingConfig). `params`: a PreprocessConfig. Returns the session and extra per-frame
    arrays (time_ns, locomotion_modes, errors) for `write_session`.
    """
    params = params or PreprocessConfig()
    simulator_config = simulator_config or SimulatorConfig()
    walker, mounting_pitch, rng = session_walker(
        seed, settings.vary_walker, simulator_config, settings.mounting_error_deg
    )
    try:
        course = make_course(preset, seed)
    except ValueError as e:
        raise InferenceError(str(e)) from None
    sim = Simulator(course, seed=seed, fps=settings.fps, **walker)
    mounting = replace(mounting or MountingConfig(), pitch_deg=mounting_pitch)
    imu_error = OrientationError(settings.imu_error, rng)

    n = int(sim.duration_s * settings.fps)
    if settings.max_frames:
        n = min(n, settings.max_frames)
    images = np.zeros((n, params.grid_size, params.grid_size), np.uint8)
    labels = np.zeros(n, np.int64)
    flags, locomotion_modes, errors = [], [], []
    time_ns = np.zeros(n, np.int64)
    for k in range(n):
        t = k / settings.fps
        frame = sim.render(t, k)
        truth = frame.truth
        q = imu_error.apply(np.asarray(truth["thigh_quaternion"], dtype=np.float64), t)
        pre = preprocess_frame(frame, q, params, mounting=mounting)
        images[k] = pre.image
        labels[k] = MODES.index(truth["mode"])
        flags.append(pre.flag)
        locomotion_modes.append(truth.get("locomotion_mode", ""))
        errors.append(truth.get("error", ""))
        time_ns[k] = frame.device_time_ns
        if progress:
            progress(1)
    meta = {
        "seed": seed,
        "fps": settings.fps,
        "preprocess": preprocess_metadata(params, mounting),
        "walker": walker,
        "imu_error": dataclasses.asdict(settings.imu_error),
        "mounting_error_deg": settings.mounting_error_deg,
        "course": [[s.mode, round(float(s.length_m), 3)] for s in course.segments],
    }
    session = LabeledSession(
        name=f"{preset}-{seed:06d}",
        images=images,
        labels=labels,
        preset=preset,
        source="synth",
        flags=np.array(flags, dtype=str),
        meta=meta,
        locomotion_modes=np.array(locomotion_modes, dtype=str),
        errors=np.array(errors, dtype=str),
    )
    extra = {"locomotion_modes": session.locomotion_modes, "errors": session.errors}
    return session, {"time_ns": time_ns, "extra": extra}


def synth_dataset(
    out: str | os.PathLike,
    count: int,
    preset: str,
    base_seed: int,
    params=None,
    settings: SynthSettings = SynthSettings(),
    simulator_config=None,
    workers: int = 1,
    show_progress: bool = True,
    cluster: str | None = None,
    mounting=None,
) -> list[Path]:
    """Render `count` sessions into `out` (one .npz each) with a progress bar over sessions:
    `workers` processes, or `cluster` (a Ray cluster's address or "local"), one task a
    session (capture.corpus.jobs)."""
    plan = session_plan(count, preset, base_seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    where = jobs.choose(cluster, workers)
    paths = [out / f"{p}-{s:06d}.npz" for p, s in plan]
    tasks = [
        jobs.Task(
            path.name,
            _synth_job,
            (p, s, params, mounting, settings, simulator_config, jobs.task_path(where, path)),
        )
        for path, (p, s) in zip(paths, plan)
    ]
    jobs.run(
        tasks,
        where,
        desc="synth",
        unit="session",
        show_progress=show_progress,
    )
    return paths


def _synth_job(preset, seed, params, mounting, settings, simulator_config, path) -> tuple[str, int]:
    session, extra = render_synth_session(
        preset, seed, params, settings, simulator_config, mounting=mounting
    )
    write_session(path, session, extra["time_ns"], extra["extra"])
    return path, len(session)
