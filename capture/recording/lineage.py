"""A recording's identity and lineage.

Every recording carries its identity: a unique id (the "recording" metadata record) and
the trial (subject, condition, trial in "session"). A derived file (a replay, a copy with
corrected labels, a recovered copy) has its own id and a "derivation" record naming its
source (id and file name) and how it was made. Derived files sit beside their source
with a name that says what they are (`.replay.mcap`, `_corrected.mcap`,
`.recovered.mcap`); the metadata, not the name, decides. Files without derivation
records are recognised by the records their writers left (software.replay_of,
corrections, recovery) and by their names.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from capture.recording.reader import Recording

RECORDING, REPLAY, CORRECTED, RECOVERED = "recording", "replay", "corrected", "recovered"
DERIVED_KINDS = (REPLAY, CORRECTED, RECOVERED)

_DERIVED_NAMES = (
    (re.compile(r"^(?P<source>.+)\.replay\d*\.mcap$"), REPLAY),
    (re.compile(r"^(?P<source>.+)_corrected\d*\.mcap$"), CORRECTED),
    (re.compile(r"^(?P<source>.+)\.recovered\d*\.mcap$"), RECOVERED),
)


def derivation(source: Recording, new_id: str, kind: str, how: str, **extra) -> dict:
    """The "derivation" metadata record of a file made from `source`."""
    subject, condition, trial = source.trial
    return {
        "id": new_id,
        "kind": kind,
        "source_id": source.id,
        "source_name": source.path.name,
        "how": how,
        "subject": subject,
        "condition": condition,
        "trial": trial,
        **extra,
    }


@dataclass
class Member:
    """One recording of a corpus: its identity and lineage."""

    path: Path
    id: str
    kind: str  # recording | replay | corrected | recovered
    trial: tuple[str, str, int | None]
    complete: bool
    source_id: str = ""
    source_name: str = ""
    how: str = ""
    supersedes: list[str] = field(default_factory=list)
    mtime: float = 0.0

    @property
    def trial_name(self) -> str:
        subject, condition, trial = self.trial
        return f"{subject or '?'} {condition or '?'} trial {trial if trial is not None else '?'}"


def describe(rec: Recording) -> Member:
    """The identity and lineage of an open recording (any age of file)."""
    meta = rec.metadata
    d = meta.get("derivation") or {}
    kind, source_id, source_name, how = RECORDING, "", "", ""
    if d.get("kind") in DERIVED_KINDS:
        kind = d["kind"]
        source_id, source_name, how = (
            str(d.get("source_id") or ""),
            str(d.get("source_name") or ""),
            str(d.get("how") or ""),
        )
    elif "corrections" in meta:
        kind, source_name = CORRECTED, str(meta["corrections"].get("source") or "")
        how = "label corrections"
    elif "recovery" in meta:
        kind, source_name = RECOVERED, str(meta["recovery"].get("source") or "")
        how = "recovered"
    elif meta.get("software", {}).get("replay_of"):
        kind, source_name = REPLAY, str(meta["software"]["replay_of"])
        how = f"replay with model {str(meta['software'].get('model_hash', ''))[:12] or '?'}"
    else:
        for pattern, named in _DERIVED_NAMES:
            m = pattern.match(rec.path.name)
            if m:
                kind, source_name, how = named, m.group("source") + ".mcap", f"{named} (by name)"
                break
    # Only an original's "recording" id is its own: older derived files copy their source's.
    own_id = rec.id if kind == RECORDING or d else "file:"
    if own_id.startswith("file:"):  # no id in the file: its path stands in
        own_id = f"file:{rec.path.resolve()}"
    supersedes = meta.get("session", {}).get("supersedes") or []
    try:
        mtime = rec.path.stat().st_mtime
    except OSError:
        mtime = 0.0
    return Member(
        path=rec.path,
        id=own_id,
        kind=kind,
        trial=rec.trial,
        complete=rec.complete,
        source_id=source_id,
        source_name=source_name,
        how=how,
        supersedes=list(supersedes) if isinstance(supersedes, list) else [],
        mtime=mtime,
    )
