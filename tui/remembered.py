"""What walkcap remembers between sessions: ~/.config/walkcap/last_session.json.

Only what the next session's form needs: the subject, condition and trial confirmed last,
the operator, and each subject's body data (tui.subject.REMEMBERED_FIELDS) with the day it was
last used. Notes are never remembered (they belong to one trial and may hold what must not
be kept). A subject not seen for more than `[session] remember_days` is dropped when the
file is next read or written; `walkcap forget SUBJECT` drops one at once. The file is
readable by its owner only (0600), in a folder of the owner's only (0700).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import logging
import os
from pathlib import Path

from capture.errors import CaptureError
from capture.live.trials import SubjectInfo
from devices.files import check_replaceable
from tui.subject import REMEMBERED_FIELDS, SUBJECT_FIELDS

log = logging.getLogger(__name__)

REMEMBER_DAYS = 90  # the default of [session] remember_days
_FORM = ("subject", "condition", "trial")  # the last form: all the file keeps of it


def last_session_path() -> Path:
    return Path(os.path.expanduser("~")) / ".config" / "walkcap" / "last_session.json"


def _today() -> str:
    return dt.date.today().isoformat()


@dataclasses.dataclass
class Remembered:
    """last_session.json: the form confirmed last, the operator, each subject's own fields."""

    last: SubjectInfo = dataclasses.field(default_factory=SubjectInfo)
    operator: str = ""
    subjects: dict[str, dict] = dataclasses.field(default_factory=dict)  # with "last_seen"

    def subject_fields(self, subject: str) -> dict:
        """`subject`'s own remembered fields; empty ones for a subject not seen before."""
        blank = SubjectInfo()
        fields = {k: getattr(blank, k) for k in SUBJECT_FIELDS}
        fields.update(
            {k: v for k, v in self.subjects.get(subject, {}).items() if k in REMEMBERED_FIELDS}
        )
        return fields

    def form_for(
        self, subject: str, condition: str, folder: str | os.PathLike | None
    ) -> SubjectInfo:
        """The form for `subject` and `condition`: that subject's own fields and the next
        free trial in `folder` (from the remembered trial when the subject and condition
        are the ones confirmed last, else from 1)."""
        from capture.recording.naming import next_free_trial, trial_files

        same = subject == self.last.subject and condition == self.last.condition
        start = self.last.trial if same else 1
        taken = trial_files(folder, subject, condition) if folder is not None else {}
        return dataclasses.replace(
            self.last,
            subject=subject,
            condition=condition,
            trial=next_free_trial(taken, start),
            **self.subject_fields(subject),
        )


def prune(subjects: dict[str, dict], days: int, today: str) -> dict[str, dict]:
    """The subjects last seen within `days` of `today` (ISO dates); 0 days: none."""
    if days <= 0:
        return {}
    try:
        limit = dt.date.fromisoformat(today) - dt.timedelta(days=days)
    except ValueError:
        return {}
    kept = {}
    for subject, fields in subjects.items():
        try:
            seen = dt.date.fromisoformat(str(fields.get("last_seen", "")))
        except ValueError:
            continue  # no day to hold it to: not kept
        if seen >= limit:
            kept[subject] = fields
    return kept


def load_remembered(
    path: Path | None = None, days: int = REMEMBER_DAYS, today: str | None = None
) -> Remembered:
    """What was confirmed last time, subjects older than `days` left out; defaults when
    there is none or it is unreadable."""
    path = path or last_session_path()
    try:
        data = json.loads(path.read_text())
        info = SubjectInfo(**{k: v for k, v in data.items() if k in _FORM})
        info.validate()
    except FileNotFoundError:
        return Remembered()
    except (OSError, ValueError, TypeError, AttributeError, CaptureError) as e:
        log.warning("ignoring %s: %s", path, e)
        return Remembered()
    operator = data.get("operator")
    subjects = {}
    for subject, fields in (data.get("subjects") or {}).items():
        if isinstance(fields, dict):
            subjects[str(subject)] = {
                k: v for k, v in fields.items() if k in (*REMEMBERED_FIELDS, "last_seen")
            }
    subjects = prune(subjects, days, today or _today())
    remembered = Remembered(info, operator if isinstance(operator, str) else "", subjects)
    remembered.last = dataclasses.replace(info, **remembered.subject_fields(info.subject))
    return remembered


def load_last_session(path: Path | None = None) -> SubjectInfo:
    """The form confirmed last time; defaults when there is none or it is unreadable."""
    return load_remembered(path).last


def _write(path: Path, data: dict) -> None:
    """The file written whole, its owner's only."""
    check_replaceable(path)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        os.fchmod(f.fileno(), 0o600)  # an older file's wider mode is not kept
        f.write(json.dumps(data, indent=2))
    os.replace(tmp, path)


def save_last_session(
    info: SubjectInfo,
    path: Path | None = None,
    *,
    operator: str | None = None,
    days: int = REMEMBER_DAYS,
    today: str | None = None,
) -> None:
    """Remember `info`'s subject, condition and trial, its subject's body data (for `days`
    days; 0: none) and the operator (None: keep the remembered one)."""
    path = path or last_session_path()
    today = today or _today()
    remembered = load_remembered(path, days, today)
    subjects = dict(remembered.subjects)
    own = {k: getattr(info, k) for k in REMEMBERED_FIELDS}
    subjects[info.subject] = {**own, "last_seen": today}
    data = {k: getattr(info, k) for k in _FORM}
    data["operator"] = remembered.operator if operator is None else operator
    data["subjects"] = prune(subjects, days, today)
    try:
        _write(path, data)
    except OSError as e:  # losing the remembered form must never stop a session
        log.warning("cannot save %s: %s", path, e)


def forget(subject: str, path: Path | None = None) -> list[str]:
    """Remove every trace of `subject` from the remembered data; what was removed."""
    path = path or last_session_path()
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as e:
        raise CaptureError(f"{path}: unreadable ({e}); remove it to forget everything") from None
    if not isinstance(data, dict):
        data = {}
    removed = []
    subjects = data.get("subjects") if isinstance(data.get("subjects"), dict) else {}
    if subject in subjects:
        del subjects[subject]
        removed.append("body data")
    if data.get("subject") == subject:
        removed.append("the last form")
        data = {"operator": data.get("operator", "")}  # the form and anything beside it
    if removed:
        data["subjects"] = subjects
        _write(path, data)
    return removed
