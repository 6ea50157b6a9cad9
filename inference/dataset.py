"""Labelled sessions for the terrain classifier: one code path for every source.

A `LabeledSession` is one walk: its preprocessed 100 x 100 images, a mode index per frame
(-1: unlabelled) and where it came from. Training, validation and evaluation only ever
see LabeledSessions, whatever wrote them:
- synthesized sessions (`walkcap synth --format dataset`): one compressed .npz per walk,
  written by `capture.corpus.dataset.render_synth_session` + `write_session`, read by
  `read_session`;
- recordings with operator labels (.mcap): `capture.corpus.dataset.labeled_session` (the
  recorded /camera/binary_image, labelled with the operator's mode in force at each
  frame; frames before the first label are unlabelled).

Synthesizing sessions and finding them in files is capture's (capture.corpus.dataset); this module
holds the record and its file format, which training and evaluation read.

The .npz layout (format "walkcap-dataset", version 1): `images` (N, 1250) uint8 from
np.packbits of the flattened 0/1 images, `labels` (N,) int8 mode indices (MODES order),
`flags` (N,) str (preprocessing flag, "" when fine), `time_ns` (N,) int64, `locomotion_modes` and
`errors` (N,) str (simulator truth, for diagnostics), `meta` a JSON string (preset, seed,
fps, preprocessing parameters, walker, IMU noise). Nothing in it needs pickle.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from devices.files import check_replaceable
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
    # the walker itself is in and the frame's error image kind ("" for none).
    locomotion_modes: np.ndarray | None = None
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
            locomotion_modes=part(self.locomotion_modes),
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
    path = check_replaceable(path)
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
            locomotion_modes = z["locomotion_modes"] if "locomotion_modes" in z.files else None
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
        or any(v is not None and len(v) != len(labels) for v in (locomotion_modes, errors))
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
        locomotion_modes=locomotion_modes,
        errors=errors,
    )


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
