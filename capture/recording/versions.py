"""The recording format's version, and the one path by which files of an older version are read.

Every file names its version in the "recording" metadata record (`format_version`,
capture.recording.topics.FORMAT_VERSION when written). The rule:

- the version goes up whenever what the writer puts in a file changes so that the same
  reading code would read an older file differently (a field added that readers rely on,
  a value's encoding, a record's meaning);
- a file of this version is read as it is;
- a file of an older version, or one without a readable "recording" record, is read
  through `upgrade_metadata` and `upgrade_message` below, which turn what it holds into
  what this version holds: no other reading code knows about older files;
- a file of a newer version is refused with one line.

Version 4 -> 5:
- /tf: in 5 it holds the camera's orientation in the leveled frame the clouds are in
  (camera -> world, inference.preprocess.camera_orientation), as its "camera" child
  frame says; up to 4 it held the IMU's orientation (IMU -> ENU world) at the frame's
  time. Read from an older file, /tf is turned into the camera's with the mounting its
  "software" record names (`preprocess.mounting_*`; the nominal mounting where it names
  none). Nothing else changed.

Version 3 -> 4:
- chunk digests: a finished file of 4 holds a `chunk_digests` metadata record
  (capture.recording.chunk_digests) with the CRC of every region the writer wrote and
  the figures `walkcap info` needs, so it reads them without decompressing a chunk. A
  version 3 file has none: `info` reads it through the streaming scan. Nothing else
  changed: a version 3 file is read as version 4 is.

Version 2 -> 3:
- record digests: in 3 every header, metadata, schema and channel record has its digest
  in a `record_digests` metadata record (capture.recording.digests), checked on reading;
  a record without one is damage. A version 2 file has none: its records are read as
  they are, unchecked. Nothing else changed: a version 2 file is read as version 3 is.

Version 1 -> 2:
- metadata values: in 2 every value is JSON; in 1 they are plain strings unless the
  "recording" record says `metadata_values: json` (the known fields are typed here, and
  lists and objects, written as JSON text, decoded); "derivation" records are JSON in
  any file (recovered or corrected copies add them).
- /inference/fused: in 2 every message names the frame that produced it
  (`source_frame_index`); in 1 it may be missing, and then it is the frame it refers to.
- lineage: in 2 every derived file (a replay, a copy with corrected labels, a recovered
  copy) has a "derivation" record with its own id. In 1 a derived file is known by the
  records its writer left (software.replay_of, corrections, recovery) or by its name
  (`.replay.mcap`, `_corrected.mcap`, `.recovered.mcap`), and its "recording" id is its
  source's: its derivation is rebuilt here, with the file's path standing in for its id.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from capture.errors import CaptureError
from capture.recording import topics as T
from devices.config import MountingConfig
from inference.preprocess import camera_orientation

RawRecords = list[tuple[str, dict[str, str]]]
Records = list[tuple[str, dict[str, Any]]]

FIRST_VERSION = "1"  # files without a format_version (none were written without one)


def _number(version: str) -> int | None:
    try:
        return int(version)
    except ValueError:
        return None


def file_version(raw: RawRecords) -> str:
    """The format version a file names in its (last) "recording" record; FIRST_VERSION
    when it has none (a file cut off before its metadata)."""
    version = FIRST_VERSION
    for name, values in raw:
        if name == "recording" and "format_version" in values:
            value = T.decode_metadata_value(values["format_version"])
            version = str(value).strip()
    return version


def needs_upgrade(version: str) -> bool:
    """Whether a file's messages are read through `upgrade_message` (version 1)."""
    number = _number(version)
    return number is None or number < 2


def read_metadata(raw: RawRecords, path: Path) -> tuple[str, Records]:
    """(version, typed metadata records) of a file; a newer version is refused."""
    version = file_version(raw)
    number, current = _number(version), _number(T.FORMAT_VERSION)
    if number is None or number > current:
        raise CaptureError(
            f"{path}: recording format {version!r}, newer than this walkcap reads "
            f"(up to {T.FORMAT_VERSION}): update walkcap to read it"
        )
    if number >= 2:  # 3 adds record digests, 4 chunk digests, 5 changes /tf: no new values
        return version, [
            (name, {k: T.decode_metadata_value(v) for k, v in values.items()})
            for name, values in raw
        ]
    return version, upgrade_metadata(raw, path)


# ---- version 1 ---------------------------------------------------------------------------

# Version 1 files without JSON values hold strings: the known fields are typed here.
_INT, _FLOAT, _BOOL = "int", "float", "bool"
_STRING_FIELDS = {
    "session": {
        "height_m": _FLOAT,
        "weight_kg": _FLOAT,
        "age": _INT,
        "amputee": _BOOL,
        "residual_limb_cm": _FLOAT,
        "trial": _INT,
    },
    "recording": {
        "unix_offset_ns": _INT,
        "chunk_interval_s": _FLOAT,
        "cloud_quantum_m": _FLOAT,
        "cloud_max_points": _INT,
        "cloud_voxel_m": _FLOAT,
    },
    "recording_end": {
        k: _INT
        for k in ("messages", "chunks", "dropped", "errors", "labels", "closed_unix_time_ns")
    },
    "camera": {
        "width": _INT,
        "height": _INT,
        "fx": _FLOAT,
        "fy": _FLOAT,
        "cx": _FLOAT,
        "cy": _FLOAT,
        "min_range_m": _FLOAT,
        "max_range_m": _FLOAT,
        "from_frame_index": _INT,
    },
}

_DERIVED_NAMES = (
    (re.compile(r"^(?P<source>.+)\.replay\d*\.mcap$"), "replay"),
    (re.compile(r"^(?P<source>.+)_corrected\d*\.mcap$"), "corrected"),
    (re.compile(r"^(?P<source>.+)\.recovered\d*\.mcap$"), "recovered"),
)


def _typed_string(text: str, kind: str | None) -> Any:
    if kind is None:
        if text.startswith(("{", "[")):  # lists and objects were written as JSON text
            value = T.decode_metadata_value(text)
            return value if isinstance(value, (dict, list)) else text
        return text
    if text == "" or text == "None":
        return None
    try:
        if kind == _BOOL:
            return {"true": True, "false": False}.get(text.lower(), text)
        return int(text) if kind == _INT else float(text)
    except ValueError:
        return text


def upgrade_metadata(raw: RawRecords, path: Path) -> Records:
    """A version 1 file's metadata records as version 2 holds them: values typed, and a
    derived file's "derivation" record rebuilt (see the module's docstring)."""
    json_values = any(
        name == "recording" and T.METADATA_VALUES_KEY in values for name, values in raw
    )
    out: Records = []
    for name, values in raw:
        if json_values or name in T.JSON_ONLY_RECORDS:
            out.append((name, {k: T.decode_metadata_value(v) for k, v in values.items()}))
        else:
            kinds = _STRING_FIELDS.get(name, {})
            out.append((name, {k: _typed_string(v, kinds.get(k)) for k, v in values.items()}))
    if not any(name == "derivation" for name, _ in out):
        derived = _derivation(dict(out), path)
        if derived is not None:
            out.append(("derivation", derived))
    return out


def _derivation(meta: dict[str, dict], path: Path) -> dict | None:
    """A version 1 derived file's lineage, from its writer's records or its name."""
    if "corrections" in meta:
        kind, source, how = "corrected", meta["corrections"].get("source"), "label corrections"
    elif "recovery" in meta:
        kind, source, how = "recovered", meta["recovery"].get("source"), "recovered"
    elif meta.get("software", {}).get("replay_of"):
        software = meta["software"]
        model = str(software.get("model_hash", ""))[:12] or "?"
        kind, source, how = "replay", software["replay_of"], f"replay with model {model}"
    else:
        for pattern, named in _DERIVED_NAMES:
            m = pattern.match(path.name)
            if m:
                kind, source, how = named, m.group("source") + ".mcap", f"{named} (by name)"
                break
        else:
            return None
    return {
        "id": f"file:{path.resolve()}",  # its "recording" id is its source's, not its own
        "kind": kind,
        "source_id": "",
        "source_name": str(source or ""),
        "how": how,
    }


def upgrade_message(topic: str, data: Any) -> Any:
    """A decoded version 1 message as version 2 writes it."""
    if topic == T.FUSED and isinstance(data, dict) and "source_frame_index" not in data:
        return {**data, "source_frame_index": data["frame_index"]}
    return data


# ---- version 4 ---------------------------------------------------------------------------


def orientation_upgrade(version: str, preprocess: dict | None) -> Callable | None:
    """For a file older than version 5: a function that turns its /tf quaternion (the
    IMU's) into the camera's, with the mounting in `preprocess` (the "software" record's
    preprocessing); None for a file of 5 on. A quaternion that is not a rotation gives
    NaN."""
    number = _number(version)
    if number is not None and number >= 5:
        return None
    nominal, named = MountingConfig(), preprocess or {}
    angles = {}
    for name in ("roll_deg", "pitch_deg", "yaw_deg"):
        try:
            angles[name] = float(named.get(f"mounting_{name}", getattr(nominal, name)))
        except (TypeError, ValueError):
            angles[name] = float(getattr(nominal, name))
    mounting = MountingConfig(**angles)

    def upgrade(quaternion: np.ndarray) -> np.ndarray:
        camera = camera_orientation(quaternion, mounting)
        return np.full(4, np.nan) if camera is None else camera

    return upgrade
