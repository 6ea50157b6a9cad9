"""Labelled sessions for the terrain classifier: one code path for every source.

A `LabeledSession` is one walk: its preprocessed 100 x 100 images, a mode index per frame
(-1: unlabelled) and where it came from. Training, validation and evaluation only ever
see LabeledSessions, whatever wrote them:
- synthesized sessions (`walkcap synth --format dataset`): one compressed .npz per walk,
  written by `render_synth_session` + `write_session`, read by `read_session`;
- recordings with operator labels (.mcap): `capture.reader.labeled_session` (the
  recorded /camera/binary_image, labelled with the operator's mode in force at each
  frame; frames before the first label are unlabelled).

The .npz layout (format "walkcap-dataset", version 1): `images` (N, 1250) uint8 from
np.packbits of the flattened 0/1 images, `labels` (N,) int8 mode indices (MODES order),
`flags` (N,) str (preprocessing flag, "" when fine), `time_ns` (N,) int64, `view_modes` and
`errors` (N,) str (simulator truth, for diagnostics), `meta` a JSON string (preset, seed,
fps, preprocessing parameters, walker, IMU noise). Nothing in it needs pickle.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from devices.frames import MODES
from inference.errors import InferenceError

log = logging.getLogger(__name__)

FORMAT = "walkcap-dataset"
FORMAT_VERSION = 1
UNLABELLED = -1


@dataclass
class LabeledSession:
    """One walk's classifier inputs and labels."""

    name: str
    images: np.ndarray  # (N, H, W) uint8 0/1
    labels: np.ndarray  # (N,) int64 mode index, UNLABELLED (-1) where nobody labelled
    preset: str = ""  # "indoor" | "outdoor" | "" (unknown)
    source: str = "synth"  # "synth" | "recording"
    flags: np.ndarray | None = None  # (N,) str, preprocessing flag ("" when fine)
    meta: dict = field(default_factory=dict)
    # Simulator truth for diagnostics (synthesized sessions only), (N,) str each: the mode
    # the frame's view mostly shows ("" for none) and its error image kind ("" for none).
    view_modes: np.ndarray | None = None
    errors: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.labels)

    def labelled(self) -> LabeledSession:
        """Only the frames that carry a label."""
        keep = self.labels >= 0

        def part(values):
            return None if values is None else values[keep]

        return replace(
            self,
            images=self.images[keep],
            labels=self.labels[keep],
            flags=part(self.flags),
            view_modes=part(self.view_modes),
            errors=part(self.errors),
        )


# ---- files ---------------------------------------------------------------------------------


def write_session(
    path: str | os.PathLike,
    session: LabeledSession,
    time_ns: np.ndarray | None = None,
    extra: dict | None = None,
) -> Path:
    """Write one session as a compressed .npz (atomically). `extra`: more (N,) arrays."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(session)
    images = np.asarray(session.images, dtype=np.uint8)
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "name": session.name,
        "preset": session.preset,
        "source": session.source,
        "image_shape": list(images.shape[1:]),
        "frames": n,
        **session.meta,
    }
    arrays = {
        "images": np.packbits(images.reshape(n, -1) != 0, axis=1),
        "labels": np.asarray(session.labels, dtype=np.int8),
        "flags": np.asarray(session.flags if session.flags is not None else [""] * n, dtype=str),
        "time_ns": np.asarray(time_ns if time_ns is not None else np.zeros(n), dtype=np.int64),
        "meta": np.array(json.dumps(meta)),
    }
    for key, value in (extra or {}).items():
        arrays[key] = np.asarray(value)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    return path


def read_session(path: str | os.PathLike) -> LabeledSession:
    """Read one .npz session; InferenceError (one line) when it is not one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("format") != FORMAT:
                raise InferenceError(f"{path} is not a walkcap dataset session")
            if meta.get("format_version") != FORMAT_VERSION:
                raise InferenceError(
                    f"{path}: dataset version {meta.get('format_version')!r},"
                    f" this walkcap reads {FORMAT_VERSION}"
                )
            h, w = meta["image_shape"]
            labels = z["labels"].astype(np.int64)
            packed = z["images"]
            images = np.unpackbits(packed, axis=1, count=h * w).reshape(len(packed), h, w)
            flags = z["flags"]
            view_modes = z["view_modes"] if "view_modes" in z.files else None
            errors = z["errors"] if "errors" in z.files else None
    except InferenceError:
        raise
    except FileNotFoundError:
        raise InferenceError(f"dataset file not found: {path}") from None
    except Exception as e:  # zip, JSON, key and shape errors all mean a broken file
        raise InferenceError(
            f"{path} is not a readable dataset session: {type(e).__name__}: {e}"
        ) from None
    if (
        len(images) != len(labels)
        or labels.max(initial=-1) >= len(MODES)
        or any(v is not None and len(v) != len(labels) for v in (view_modes, errors))
    ):
        raise InferenceError(f"{path}: images and labels do not match")
    return LabeledSession(
        name=meta.get("name") or path.stem,
        images=images,
        labels=labels,
        preset=meta.get("preset", ""),
        source=meta.get("source", "synth"),
        flags=flags,
        meta=meta,
        view_modes=view_modes,
        errors=errors,
    )


# Readers by file suffix; ".mcap" (the recorded images and the operator's labels) falls back
# to _read_recording. Every source yields LabeledSessions: one dataset code path.
READERS: dict[str, Callable[[Path], LabeledSession]] = {".npz": read_session}


def register_reader(suffix: str, reader: Callable[[Path], LabeledSession]) -> None:
    READERS[suffix.lower()] = reader


def _read_recording(path: Path) -> LabeledSession:
    """A walkcap recording: its classifier inputs, labelled by the operator's mode."""
    from capture.errors import CaptureError
    from capture.reader import labeled_session  # capture reads files; inference stays pure

    try:
        return labeled_session(path)
    except CaptureError as e:
        raise InferenceError(str(e)) from None


def find_session_files(paths: list[str | os.PathLike]) -> list[Path]:
    """Files of sessions: the given files, and every known file in the given folders."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(
                f
                for f in p.rglob("*")
                if f.suffix.lower() in (*READERS, ".mcap") and ".tmp" not in f.name
            )
            if not found:
                raise InferenceError(f"no sessions (.npz or .mcap) in {p}")
            files += found
        elif p.exists():
            files.append(p)
        else:
            raise InferenceError(f"no such file or folder: {p}")
    return files


def read_sessions(paths: list[str | os.PathLike]) -> list[LabeledSession]:
    """Every session under `paths` (files or folders), whatever its source."""
    sessions = []
    for f in find_session_files(paths):
        reader = READERS.get(
            f.suffix.lower(), _read_recording if f.suffix.lower() == ".mcap" else None
        )
        if reader is None:
            raise InferenceError(f"{f}: unknown session file type {f.suffix!r}")
        sessions.append(reader(f))
    return sessions


def summarize(sessions: list[LabeledSession]) -> dict:
    """Counts for metadata and reports: sessions, frames, per class, per preset."""
    out: dict = {
        "sessions": len(sessions),
        "frames": 0,
        "per_class": dict.fromkeys(MODES, 0),
        "per_preset": {},
        "flagged": 0,
    }
    for s in sessions:
        n = int(np.count_nonzero(s.labels >= 0))
        out["frames"] += n
        counts = np.bincount(s.labels[s.labels >= 0], minlength=len(MODES))
        for mode, c in zip(MODES, counts):
            out["per_class"][mode] += int(c)
        preset = s.preset or "unknown"
        out["per_preset"][preset] = out["per_preset"].get(preset, 0) + n
        if s.flags is not None:
            out["flagged"] += int(np.count_nonzero(s.flags[s.labels >= 0] != ""))
    return out


# ---- synthesized sessions -------------------------------------------------------------------


@dataclass(frozen=True)
class SynthSettings:
    """How a synthesized session is made, beyond its preset and seed."""

    fps: float = 15.0  # the paper's camera rate
    imu_noise_deg: float = 0.7  # per-frame orientation noise (1 sigma per axis)
    # Per session: the IMU's roll and pitch bias and the mounting's pitch error (1 sigma).
    # `walkcap calibrate` fits the mounting through the IMU's own orientation on level
    # ground, so it absorbs the bias present then: what is left is the bias's change since
    # and the calibration's residual (strap settling). Counting both in full (0.7 + 1.0
    # degrees) would give 1.2 degrees of pitch per session, the slope every image of that
    # session is off by: up ramps of 5-6 degrees would show 3-4 degrees and be taken for
    # level ground.
    imu_bias_deg: float = 0.5
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


def _walker(rng: np.random.Generator, vary: bool, config) -> dict:
    base = {
        "speed_mps": config.speed_mps,
        "cadence_spm": config.cadence_spm,
        "camera_height_m": config.camera_height_m,
        "camera_tilt_deg": config.camera_tilt_deg,
    }
    if not vary:
        return base
    # Subjects and mountings differ: speed, cadence, thigh length, strap angle.
    return {
        "speed_mps": float(rng.uniform(0.85, 1.35)),
        "cadence_spm": float(rng.uniform(90.0, 120.0)),
        "camera_height_m": float(rng.uniform(0.48, 0.62)),
        "camera_tilt_deg": float(rng.uniform(28.0, 42.0)),
    }


def _small_rotation(rng: np.random.Generator, sigma_deg: float) -> np.ndarray:
    """A random rotation quaternion of about sigma_deg per axis."""
    from devices.rotations import quat_from_euler

    roll, pitch, yaw = np.radians(rng.normal(0.0, sigma_deg, 3))
    return quat_from_euler(roll, pitch, yaw)


def render_synth_session(
    preset: str,
    seed: int,
    params=None,
    settings: SynthSettings = SynthSettings(),
    simulator_config=None,
    progress: Callable[[int], None] | None = None,
) -> tuple[LabeledSession, dict]:
    """Walk one simulated course and preprocess every frame as the live pipeline does.

    The IMU orientation is the simulator's thigh orientation with a per-session bias and
    per-frame noise; the preprocessing uses the mounting the operator would have
    calibrated (true tilt plus a small error). Returns the session and extra per-frame
    arrays (time_ns, view_modes, errors) for `write_session`.
    """
    from capture.config import SimulatorConfig
    from devices.rotations import quat_from_euler, quat_multiply
    from devices.simulator import Simulator, make_course
    from inference.preprocess import PreprocessParams, preprocess_frame

    params = params or PreprocessParams()
    simulator_config = simulator_config or SimulatorConfig()
    rng = np.random.default_rng([seed, 7919])
    walker = _walker(rng, settings.vary_walker, simulator_config)
    try:
        course = make_course(preset, seed)
    except ValueError as e:
        raise InferenceError(str(e)) from None
    sim = Simulator(course, seed=seed, **walker)
    mounting_pitch = walker["camera_tilt_deg"] + float(rng.normal(0.0, settings.mounting_error_deg))
    params = replace(params, mounting_pitch_deg=mounting_pitch)
    roll_b, pitch_b = np.radians(rng.normal(0.0, settings.imu_bias_deg, 2))
    bias = quat_from_euler(roll_b, pitch_b, 0.0)

    n = int(sim.duration_s * settings.fps)
    if settings.max_frames:
        n = min(n, settings.max_frames)
    images = np.zeros((n, params.grid_size, params.grid_size), np.uint8)
    labels = np.zeros(n, np.int64)
    flags, view_modes, errors = [], [], []
    time_ns = np.zeros(n, np.int64)
    for k in range(n):
        t = k / settings.fps
        frame = sim.render(t, k)
        truth = frame.truth
        q = np.asarray(truth["thigh_quaternion"], dtype=np.float64)
        # Sensor -> world error applied in the world frame, as a drifting filter would.
        q = quat_multiply(quat_multiply(_small_rotation(rng, settings.imu_noise_deg), bias), q)
        pre = preprocess_frame(frame, q, params)
        images[k] = pre.image
        labels[k] = MODES.index(truth["mode"])
        flags.append(pre.flag)
        view_modes.append(truth.get("view_mode", ""))
        errors.append(truth.get("error", ""))
        time_ns[k] = frame.device_time_ns
        if progress:
            progress(1)
    meta = {
        "seed": seed,
        "fps": settings.fps,
        "preprocess": params.to_dict(),
        "walker": walker,
        "imu_noise_deg": settings.imu_noise_deg,
        "imu_bias_deg": settings.imu_bias_deg,
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
        view_modes=np.array(view_modes, dtype=str),
        errors=np.array(errors, dtype=str),
    )
    extra = {"view_modes": session.view_modes, "errors": session.errors}
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
) -> list[Path]:
    """Render `count` sessions into `out` (one .npz each) with a progress bar over frames."""
    from tqdm import tqdm

    plan = session_plan(count, preset, base_seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [
        (p, s, params, settings, simulator_config, str(out / f"{p}-{s:06d}.npz")) for p, s in plan
    ]
    paths: list[Path] = []
    with tqdm(total=len(jobs), unit="session", desc="synth", disable=not show_progress) as bar:
        if workers > 1 and len(jobs) > 1:
            import multiprocessing as mp

            with mp.get_context("spawn").Pool(workers) as pool:
                for path, frames in pool.imap(_synth_job, jobs):
                    paths.append(Path(path))
                    bar.set_postfix(frames=frames)
                    bar.update(1)
        else:
            for job in jobs:
                path, frames = _synth_job(job)
                paths.append(Path(path))
                bar.set_postfix(frames=frames)
                bar.update(1)
    return paths


def _synth_job(job) -> tuple[str, int]:
    preset, seed, params, settings, simulator_config, path = job
    session, extra = render_synth_session(preset, seed, params, settings, simulator_config)
    write_session(path, session, extra["time_ns"], extra["extra"])
    return path, len(session)
