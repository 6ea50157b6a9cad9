"""A trial: the session form (subject, condition, trial number) and the file it records
into, one per trial, named from the form and the time, with the metadata it carries."""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import re
from dataclasses import dataclass
from pathlib import Path

from capture import config as config_mod
from capture.errors import CaptureError
from capture.recording.metadata import DevicesRecord, SessionRecord, SoftwareRecord, as_dicts

TRIAL_MAX = 99_999  # trial numbers name files (t01 ... t99999) and fit every integer field
# The default of [session] subject_pattern: a code of letters then digits (S01, P07, OP1).
SUBJECT_PATTERN = config_mod.SessionConfig.subject_pattern


def check_pseudonym(subject: str, pattern: str = SUBJECT_PATTERN) -> None:
    """CaptureError, in one line naming the pattern, when `subject` is no id of the study's
    pattern ([session] subject_pattern): a name in the id field goes into every file name."""
    try:
        fits = re.fullmatch(pattern, subject) is not None
    except re.error:
        fits = False
    if not fits:  # the id is not repeated: it may be a name, and errors reach logs
        raise CaptureError(
            f"subject id: the study's pattern is {pattern} ([session] subject_pattern): "
            "a pseudonymous code such as S01, never a name"
        )


@dataclass
class SubjectInfo:
    """The session form: the paper's subject tables plus condition and trial."""

    subject: str = "S01"  # pseudonymous id, never a name
    height_m: float | None = None
    weight_kg: float | None = None
    age: int | None = None
    sex: str = ""  # female | male | other | ""
    amputee: bool = False
    side: str = ""  # left | right (amputees)
    residual_limb_cm: float | None = None
    condition: str = "indoor"  # indoor | outdoor | free text
    trial: int = 1
    notes: str = ""

    def validate(self, pattern: str | None = None) -> None:
        """CaptureError naming the first field out of range; `pattern`: the subject id must
        also fit it (check_pseudonym), as every id an operator types must."""
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,32}", self.subject):
            raise CaptureError(
                "subject id: 1-32 letters, digits, '-' or '_' (pseudonymous, no names)"
            )
        if self.height_m is not None and not 0.5 <= self.height_m <= 2.5:
            raise CaptureError("height: expected metres between 0.5 and 2.5")
        if self.weight_kg is not None and not 20 <= self.weight_kg <= 300:
            raise CaptureError("weight: expected kilograms between 20 and 300")
        if self.age is not None and not 1 <= self.age <= 120:
            raise CaptureError("age: expected years between 1 and 120")
        if self.sex not in ("", "female", "male", "other"):
            raise CaptureError("sex: female, male, other or empty")
        if self.side not in ("", "left", "right"):
            raise CaptureError("side: left, right or empty")
        if self.amputee and not self.side:
            raise CaptureError("side: required for an amputee (left or right)")
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,32}", self.condition):
            raise CaptureError("condition: 1-32 letters, digits, '-' or '_' (e.g. indoor)")
        if not 1 <= self.trial <= TRIAL_MAX:
            raise CaptureError(f"trial: a number from 1 to {TRIAL_MAX}")
        if pattern is not None:
            check_pseudonym(self.subject, pattern)

    def to_metadata(self) -> dict:
        """The form as the "session" metadata record: typed values (None: not given)."""
        return dataclasses.asdict(self)


@dataclass
class TrialFile:
    """Where a trial records."""

    path: Path
    info: SubjectInfo  # the form, with the trial number it records under
    supersedes: list[str]  # the earlier files of the same trial it stands in for
    notice: str  # why the trial number is not the one asked ("": it is)


def trial_file(folder: Path, info: SubjectInfo, existing: str) -> TrialFile:
    """The file of trial `info` in `folder` (created if need be).

    A trial that has files in the folder already is never recorded twice by accident
    (capture.recording.naming.trial_conflict): `existing` "next" records the next free trial
    number instead (and says so in the notice), "error" refuses, "overwrite" records it
    again, the new file superseding the earlier ones (kept on disk; corpora leave them out).
    """
    from capture.recording.naming import trial_conflict

    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CaptureError(f"cannot create the recordings folder {folder}: {e.strerror}") from None
    trial, supersedes, notice = trial_conflict(
        folder, info.subject, info.condition, info.trial, existing
    )
    info = dataclasses.replace(info, trial=trial)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = folder / f"{info.subject}_{info.condition}_t{info.trial:02d}_{stamp}.mcap"
    return TrialFile(path, info, supersedes, notice)


def trial_metadata(
    config: config_mod.Config, trial: TrialFile, devices: dict, software: dict
) -> dict[str, dict]:
    """The trial's metadata records: its form and operator ("session"), the "devices" and
    "software" records (capture.live.devices, capture.live.pipeline)."""
    session = SessionRecord.build(**trial.info.to_metadata(), operator=config.session.operator)
    if trial.supersedes:
        session = session.replaced(supersedes=trial.supersedes)
    return as_dicts(
        session,
        DevicesRecord.from_dict(devices),
        SoftwareRecord.from_dict(software),
    )


def trial_attachments(config: config_mod.Config, model_metadata: dict) -> dict[str, bytes]:
    """The configuration and the model's metadata, attached to every trial's file."""
    return {
        "walkcap.toml": config_mod.dumps(config, secrets=False).encode(),
        "model.json": json.dumps(model_metadata, indent=2, default=str).encode(),
    }
