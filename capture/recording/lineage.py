"""A recording's identity and lineage.

Every recording carries its identity: a unique id (the "recording" metadata record) and
the trial (subject, condition, trial in "session"). A derived file (a replay, a copy with
corrected labels, a recovered copy) has its own id and a "derivation" record naming its
source (id and file name) and how it was made. Derived files sit beside their source
with a name that says what they are (`.replay.mcap`, `_corrected.mcap`,
`.recovered.mcap`); the metadata, not the name, decides. (Derived files of format
version 1 get their "derivation" record from capture.recording.versions on reading.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from capture.recording.metadata import DerivationRecord
from capture.recording.reader import Recording

RECORDING, REPLAY, CORRECTED, RECOVERED = "recording", "replay", "corrected", "recovered"
DERIVED_KINDS = (REPLAY, CORRECTED, RECOVERED)
# A copy made for sharing (capture.corpus.share) stands for its trial on its own: its
# source stays with the lab, so among shared copies it is the trial's original.
SHARED = "shared"
ORIGINAL_KINDS = (RECORDING, SHARED)


def derivation(source: Recording, new_id: str, kind: str, how: str, **extra) -> dict:
    """The "derivation" metadata record of a file made from `source`."""
    subject, condition, trial = source.trial
    return DerivationRecord.build(
        id=new_id,
        kind=kind,
        source_id=source.id,
        source_name=source.path.name,
        how=how,
        subject=subject,
        condition=condition,
        trial=trial,
        **extra,
    ).to_dict()


@dataclass
class Member:
    """One recording of a corpus: its identity and lineage."""

    path: Path
    id: str
    kind: str  # recording | replay | corrected | recovered | shared
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
    """The identity and lineage of an open recording."""
    meta = rec.meta
    d = meta.derivation
    kind, source_id, source_name, how = RECORDING, "", "", ""
    if d.kind in (*DERIVED_KINDS, SHARED):
        kind = d.kind
        source_id, source_name, how = (
            str(d.source_id or ""),
            str(d.source_name or ""),
            str(d.how or ""),
        )
    own_id = rec.id
    if own_id.startswith("file:"):  # no id in the file: its path stands in
        own_id = f"file:{rec.path.resolve()}"
    supersedes = meta.session.supersedes or []
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
