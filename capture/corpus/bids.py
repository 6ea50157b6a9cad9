"""Recordings as a BIDS-Motion dataset (`walkcap export --format bids -o DATASET`).

    from capture.corpus import bids
    result = bids.export(["recordings/"], "dataset/", study)   # study: capture.config.StudyConfig

The layout (docs/export.md#bids): a walkcap subject is `sub-<subject>`, its condition (the
course walked) `task-<condition>`, its trial number `run-<trial>`; walkcap numbers trials
per subject and condition, so a run is one trial. BIDS labels are letters and digits only:
a subject or condition with anything else is refused, by name, before anything is written.

    dataset_description.json  README  participants.tsv/.json
    sub-S01/sub-S01_scans.tsv/.json
    sub-S01/motion/sub-S01_task-indoor_run-1_tracksys-imu_motion.tsv/.json, _channels.tsv/.json
    sub-S01/motion/sub-S01_task-indoor_run-1_events.tsv/.json
    sourcedata/sub-S01/<the original .mcap> and its .journal.jsonl, byte for byte
    derivatives/walkcap/dataset_description.json
    derivatives/walkcap/sub-S01/motion/sub-S01_task-indoor_run-1_events.tsv/.json (a row per frame)

One file per trial, as every export picks it (capture.corpus.selection: superseded trials
and unreadable files are left out and listed). Into an existing dataset: new trials join,
a trial already there is skipped, or replaced with `overwrite`. A subject's body data
(participants.tsv) that a recording contradicts is refused with both values.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from capture.corpus import bids_trial as BT
from capture.corpus import export as export_mod
from capture.corpus import selection
from capture.errors import CaptureError
from capture.recording import personal
from capture.recording.journal import journal_path
from capture.recording.metadata import Metadata, SessionRecord
from capture.recording.reader import open_recording

BIDS_VERSION = "1.10.0"
HED_VERSION = "8.3.0"  # no HED tags are written; the schema a later annotation uses
LABEL = re.compile(r"^[A-Za-z0-9]+$")
LABEL_RULE = "BIDS labels are letters and digits only (A-Z, a-z, 0-9)"
# the [study] keys BIDS recommends (the validator warns without them)
RECOMMENDED_STUDY_KEYS = (
    "name",
    "authors",
    "license",
    "institution_name",
    "institution_address",
    "institution_department",
    "instructions",
)

# participants.tsv: column, the session form's field, its description (units, levels)
PARTICIPANT_COLUMNS = (
    ("age", "age", {"Description": "age at the recording", "Units": "year"}),
    (
        "sex",
        "sex",
        {
            "Description": "sex as given on the session form",
            "Levels": {"female": "female", "male": "male", "other": "other"},
        },
    ),
    ("height", "height_m", {"Description": "body height", "Units": "m"}),
    ("weight", "weight_kg", {"Description": "body weight", "Units": "kg"}),
    (
        "amputee",
        "amputee",
        {
            "Description": "the participant has a lower-limb amputation",
            "Levels": {"yes": "amputee", "no": "not an amputee"},
        },
    ),
    (
        "amputation_side",
        "side",
        {
            "Description": "the amputated side",
            "Levels": {"left": "left leg", "right": "right leg"},
        },
    ),
    (
        "residual_limb_length",
        "residual_limb_cm",
        {"Description": "length of the residual limb", "Units": "cm"},
    ),
)


@dataclass
class Trial:
    """One trial's place in the dataset."""

    path: Path  # the recording
    subject: str
    task: str
    run: int
    original: Path | None = None  # a derived file's (corrected, recovered) original

    @property
    def stem(self) -> str:
        return f"sub-{self.subject}_task-{self.task}_run-{self.run}"

    @property
    def motion(self) -> str:
        """The motion file, relative to the subject's folder."""
        return f"motion/{self.motion_stem}_motion.tsv"

    @property
    def motion_stem(self) -> str:
        """The tracking system's files: tracksys comes before run (BIDS entity order)."""
        return f"sub-{self.subject}_task-{self.task}_tracksys-{BT.TRACKSYS}_run-{self.run}"


@dataclass
class Result:
    written: list[Trial] = field(default_factory=list)
    skipped: list[tuple[Trial, str]] = field(default_factory=list)
    corpus: selection.Corpus | None = None


def trial_of(path: Path, trial: tuple) -> Trial:
    """A recording's sub/task/run, or a CaptureError naming the id that cannot map."""
    subject, condition, number = trial
    for what, value in (("subject", subject), ("condition", condition)):
        if not value or not LABEL.match(str(value)):
            raise CaptureError(
                f"{path.name}: {what} {value!r} cannot be a BIDS label: {LABEL_RULE}"
            )
    if number is None or int(number) < 0:
        raise CaptureError(f"{path.name}: trial {number!r} cannot be a BIDS run: a number >= 0")
    return Trial(path, str(subject), str(condition), int(number))


def participant(meta: Metadata, share: personal.ShareRules | None = None) -> dict[str, str]:
    """A recording's participants.tsv values (n/a where the form left it empty), reduced
    by the share rules when de-identifying (capture.recording.personal)."""
    session = meta.session
    if share is not None:
        reduced, _ = personal.reduce_session(session.to_dict(), share)
        session = SessionRecord.from_dict(reduced)
    out = {}
    for column, key, _ in PARTICIPANT_COLUMNS:
        v = session.value(key)
        if key == "amputee":
            v = None if v in (None, "") else ("yes" if str(v).lower() == "true" else "no")
        elif key == "side" and session.amputee in (False, "False", "false"):
            v = None
        out[column] = BT.text(v) if isinstance(v, str) else BT._number(v)
    return out


def _disagreement(sub: str, old: dict, new: dict, where: str, what: str) -> str | None:
    for column, value in new.items():
        before = old.get(column, BT.NA)
        if before != BT.NA and value != BT.NA and not _same(before, value):
            return f"sub-{sub} {column}: {where} has {before}, {what} has {value}"
    return None


def _same(a: str, b: str) -> bool:
    try:
        return float(a) == float(b)
    except ValueError:
        return a == b


# ---- the dataset ----------------------------------------------------------------------


def export(
    paths: Iterable[str | os.PathLike],
    out: str | os.PathLike,
    study,
    *,
    overwrite: bool = False,
    replays: bool = False,
    share: personal.ShareRules | None = None,
) -> Result:
    """Write (or add to) the BIDS dataset `out` from the recordings in `paths`. `share`:
    de-identify by these rules (capture.recording.personal): body data as they say, dates
    shifted, marker notes replaced; the originals then stay out of sourcedata/ (they hold
    the real dates and the notes)."""
    if share is not None:
        try:
            share.check()
        except personal.RulesError as e:
            raise CaptureError(f"--deidentify: {e}") from None
    root = Path(out)
    # the dataset's own copies under sourcedata/ are not recordings to export again
    inside = root.resolve()
    files = [f for f in selection.recording_files(paths) if inside not in f.resolve().parents]
    if not files:
        raise CaptureError(f"nothing to export: no recordings outside {root}")
    corpus = selection.select(files, replays=replays)
    if not corpus.chosen:
        raise corpus.nothing_left("nothing to export")
    if root.exists() and not root.is_dir():
        raise CaptureError(f"{root} is a file, not a folder")
    if root.is_dir() and any(root.iterdir()) and not (root / "dataset_description.json").exists():
        raise CaptureError(f"{root}: a folder that is not a BIDS dataset; choose an empty one")
    old = _read_json(root / "dataset_description.json").get("walkcap", {})
    if "deidentified" in old and bool(old["deidentified"]) != (share is not None):
        raise CaptureError(
            f"{root}: this dataset was written "
            + (
                "de-identified: add to it with --deidentify"
                if old["deidentified"]
                else "with the real dates and notes: --deidentify needs a new dataset"
            )
        )
    trials = [trial_of(m.path, m.trial) for m in corpus.chosen]
    for t, m in zip(trials, corpus.chosen, strict=True):
        original = m.path.parent / m.source_name if m.source_name else None
        if original is not None and original.is_file() and original != m.path:
            t.original = original
    seen: dict[tuple, Path] = {}
    for t in trials:
        key = (t.subject, t.task, t.run)
        if key in seen:
            raise CaptureError(
                f"{t.path.name} and {seen[key].name} are both {t.stem}: one file per trial"
            )
        seen[key] = t.path
    people = _read_tsv(root / "participants.tsv", "participant_id")
    metas = {t.path: open_recording(t.path).meta for t in trials}
    body: dict[str, tuple[dict, str]] = {}
    for t in trials:
        values = participant(metas[t.path], share)
        stored = people.get(f"sub-{t.subject}")
        if stored is not None:
            problem = _disagreement(t.subject, stored, values, "participants.tsv", t.path.name)
            if problem:
                raise CaptureError(f"{problem}; correct one of them before exporting")
        if t.subject in body:
            earlier, name = body[t.subject]
            problem = _disagreement(t.subject, earlier, values, name, t.path.name)
            if problem:
                raise CaptureError(f"{problem}; correct one of them before exporting")
            values = {k: v if v != BT.NA else earlier[k] for k, v in values.items()}
        body[t.subject] = (values, t.path.name)

    result = Result(corpus=corpus)
    root.mkdir(parents=True, exist_ok=True)
    # the dataset's own files first: a dataset cut short by a full disk is still one, each
    # participant listed before their trials
    for sub, (values, _) in body.items():
        stored = people.get(f"sub-{sub}", {})
        merged = {k: v if v != BT.NA else stored.get(k, BT.NA) for k, v in values.items()}
        people[f"sub-{sub}"] = {"participant_id": f"sub-{sub}", "species": "homo sapiens"}
        people[f"sub-{sub}"].update(merged)
    _write_participants(root, people)
    _write_descriptions(root, study, metas, share)
    for t in trials:
        scans_path = root / f"sub-{t.subject}" / f"sub-{t.subject}_scans.tsv"
        scans = _read_tsv(scans_path, "filename")
        existing = scans.get(t.motion)  # its row is written last: the trial is whole
        if existing is not None and not overwrite:
            was = existing.get("walkcap_recording_id", "")
            now = metas[t.path].recording.id or ""
            why = "already in the dataset"
            if was and now and was != now:
                why += f" from another recording ({was}); --overwrite replaces it"
            result.skipped.append((t, why))
            continue
        # the old trial (--overwrite), or what an interrupted export left of it
        _remove_trial(root, t, existing or {})
        row = _write_trial(root, t, study, share)
        if row is None:
            result.skipped.append((t, "no IMU samples: nothing for a motion file"))
            continue
        scans[t.motion] = row
        _write_scans(scans_path, scans)
        result.written.append(t)
    return result


def _write_trial(root: Path, t: Trial, study, share: personal.ShareRules | None) -> dict | None:
    """One trial's files; its scans.tsv row (None: no IMU samples, nothing written)."""
    rec = open_recording(t.path)
    meta = rec.meta
    tables = export_mod.tables(t.path)
    rate = BT.configured_rate(meta.devices)
    motion = BT.motion_file(tables["imu"], rate)
    if not motion.rows:
        return None
    folder = root / f"sub-{t.subject}" / "motion"
    prefix = folder / t.motion_stem
    _text(Path(f"{prefix}_motion.tsv"), "\n".join(motion.rows) + ("\n" if motion.rows else ""))
    _json(Path(f"{prefix}_motion.json"), BT.motion_json(meta, study, t.task, motion))
    _text(Path(f"{prefix}_channels.tsv"), BT.channels_tsv(study.imu_placement))
    _json(Path(f"{prefix}_channels.json"), BT.channels_json())
    end = rec.end_ns
    # time zero: the first IMU sample (the motion file's first row); without one, the start
    zero = motion.first_ns if motion.first_ns is not None else rec.start_ns
    events = tables["events"]
    if share is not None:  # marker notes by the rules; the marker's time stays
        kept = [
            personal.reduce_event({"device": d, "message": m}, share)
            for d, m in zip(events["device"], events["message"], strict=True)
        ]
        # file names in device events carry the trial's start time
        events["message"] = [personal.strip_file_time(e.get("message", "")) for e in kept]
    rows = BT.events_rows(tables, zero, end)
    header = "\t".join(BT.EVENT_COLUMNS)
    _text(folder / f"{t.stem}_events.tsv", "\n".join([header, *rows]) + "\n")
    _json(folder / f"{t.stem}_events.json", BT.events_json())
    # the derivative: walkcap's per-frame results on the motion file's time
    deriv = root / "derivatives" / "walkcap" / f"sub-{t.subject}" / "motion"
    head, frame_rows = BT.frames_rows(tables["frames"], zero)
    # one row per camera frame, as BIDS events: an onset and the frame's results
    frames_text = "\n".join(["\t".join(head), *frame_rows]) + "\n"
    _text(deriv / f"{t.stem}_events.tsv", frames_text)
    _json(deriv / f"{t.stem}_events.json", BT.frames_json(meta))
    # the original, byte for byte, and its journal (not when de-identifying: they hold the
    # real dates and the notes)
    # (a corrected or recovered copy: its original too)
    source_file = original_file = BT.NA
    if share is None:
        source = root / "sourcedata" / f"sub-{t.subject}"
        for path in filter(None, (t.path, t.original)):
            _copy(path, source / path.name)
            journal = journal_path(path)
            if journal.is_file():
                _copy(journal, source / journal.name)
        source_file = f"sourcedata/sub-{t.subject}/{t.path.name}"
        if t.original is not None:
            original_file = f"sourcedata/sub-{t.subject}/{t.original.name}"
    first_unix = rec.unix_time_ns(zero) if zero is not None else None
    if share is not None:
        first_unix = personal.shift_unix_ns(first_unix, personal.date_offset_ns(share, t.subject))
    return {
        "filename": t.motion,
        "acq_time": _acq_time(first_unix),
        "walkcap_recording_id": meta.recording.id if meta.recording.has("id") else BT.NA,
        "source_file": source_file,
        "original_file": original_file,
        "imu_samples": str(motion.samples),
        "imu_missing": str(motion.missing),
        "complete": "true" if rec.complete else "false",
    }


def _remove_trial(root: Path, t: Trial, row: dict) -> None:
    """A trial's files, before it is written again (--overwrite)."""
    for folder in (
        root / f"sub-{t.subject}" / "motion",
        root / "derivatives" / "walkcap" / f"sub-{t.subject}" / "motion",
    ):
        for stem in (t.stem, t.motion_stem):
            for f in folder.glob(f"{stem}_*"):
                f.unlink(missing_ok=True)
    for column in ("source_file", "original_file"):
        source = row.get(column, "")
        if source and source != BT.NA and ".." not in source:
            for f in (root / source, journal_path(root / source)):
                f.unlink(missing_ok=True)


def _acq_time(unix_ns: int | None) -> str:
    if unix_ns is None:
        return BT.NA
    seconds, ns = divmod(int(unix_ns), 1_000_000_000)
    when = dt.datetime.fromtimestamp(seconds, dt.UTC)
    return when.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns // 1000:06d}"


SCANS_COLUMNS = (
    "filename",
    "acq_time",
    "walkcap_recording_id",
    "source_file",
    "original_file",
    "imu_samples",
    "imu_missing",
    "complete",
)
SCANS_JSON = {
    "acq_time": {"Description": "the first IMU sample's time, UTC (the motion file's time zero)"},
    "walkcap_recording_id": {"Description": "the walkcap recording's unique id"},
    "source_file": {"Description": "the walkcap recording (MCAP) exported, under sourcedata/"},
    "original_file": {
        "Description": "when source_file is a corrected or recovered copy: the recording it "
        "was made from, under sourcedata/"
    },
    "imu_samples": {"Description": "rows of the motion file from recorded IMU samples"},
    "imu_missing": {"Description": "n/a rows: samples the IMU produced and the file lacks"},
    "complete": {
        "Description": "the recording was finalised; false: cut off (a crash), exported as "
        "far as it is readable",
        "Levels": {"true": "finalised", "false": "cut off"},
    },
}


def _write_scans(path: Path, scans: dict) -> None:
    lines = ["\t".join(SCANS_COLUMNS)]
    for name in sorted(scans):
        lines.append("\t".join(scans[name].get(c, BT.NA) for c in SCANS_COLUMNS))
    _text(path, "\n".join(lines) + "\n")
    _json(path.with_suffix(".json"), SCANS_JSON)


def _write_participants(root: Path, people: dict) -> None:
    columns = ["participant_id", "species"] + [c for c, _, _ in PARTICIPANT_COLUMNS]
    lines = ["\t".join(columns)]
    for pid in sorted(people):
        lines.append("\t".join(people[pid].get(c, BT.NA) for c in columns))
    _text(root / "participants.tsv", "\n".join(lines) + "\n")
    described = {
        "participant_id": {"Description": "the walkcap subject id, sub-<subject>"},
        "species": {"Description": "binomial species name (NCBI Taxonomy)"},
    }
    described.update({c: d for c, _, d in PARTICIPANT_COLUMNS})
    _json(root / "participants.json", described)


def _write_descriptions(root: Path, study, metas: dict, share) -> None:
    old = _read_json(root / "dataset_description.json")
    software = [m.software for m in metas.values()]
    versions = sorted({s.walkcap_version or "" for s in software} - {""})
    desc = {
        "Name": study.name or old.get("Name") or "walkcap dataset",
        "BIDSVersion": BIDS_VERSION,
        "DatasetType": "raw",
        "HEDVersion": HED_VERSION,
        "License": study.license or old.get("License"),
        "Authors": list(study.authors) or old.get("Authors"),
        "GeneratedBy": [
            {
                "Name": "walkcap",
                "Version": versions[-1] if versions else "unknown",
                "Description": "walkcap export --format bids",
            }
        ],
        "SourceDatasets": [{"URL": "file:sourcedata/"}]
        if share is None
        else [{"Version": "the walkcap recordings the lab keeps (not shared)"}],
        "walkcap": {
            "deidentified": share is not None,
            **({"share_rules": share.describe()} if share is not None else {}),
        },
    }
    _json(root / "dataset_description.json", {k: v for k, v in desc.items() if v})
    _text(root / "README", readme(study, share is not None))
    hashes = sorted({s.model_hash or "" for s in software} - {""})
    deriv = root / "derivatives" / "walkcap"
    old_deriv = _read_json(deriv / "dataset_description.json")
    known = set(old_deriv.get("walkcap", {}).get("model_hashes", []))
    _json(
        deriv / "dataset_description.json",
        {
            "Name": f"{desc['Name']}: walkcap's per-frame results",
            "BIDSVersion": BIDS_VERSION,
            "DatasetType": "derivative",
            "GeneratedBy": [
                {
                    "Name": "walkcap",
                    "Version": desc["GeneratedBy"][0]["Version"],
                    "Description": "terrain CNN probabilities, fused decisions and terrain "
                    "features per camera frame; classifier weights SHA-256: "
                    + ", ".join(sorted(known | set(hashes))),
                }
            ],
            "SourceDatasets": [{"URL": "file:../../"}],
            **({"Authors": desc["Authors"]} if desc.get("Authors") else {}),
            **({"License": desc["License"]} if desc.get("License") else {}),
            "HEDVersion": HED_VERSION,
            "walkcap": {"model_hashes": sorted(known | set(hashes))},
        },
    )
    _text(deriv / "README", DERIVATIVE_README)


DERIVATIVE_README = """# walkcap's per-frame results

One table per trial and camera frame (sub-<subject>/motion/*_events.tsv, a row per frame):
the terrain CNN's five probabilities and its own decision, the fused posterior and
decision (with the frame whose arrival produced it), the vote, and the terrain features
measured from the leveled depth profile (kind, slope, the slope a step ahead, riser,
tread, direction, steps). Onsets are seconds from the raw trial's first IMU sample, the
time of its motion file. The sidecar names every column, the walkcap version and the
SHA-256 of the classifier's weights.
"""


def readme(study, deidentified: bool) -> str:
    name = study.name or "walkcap dataset"
    return f"""# {name}

Assistive-walking data recorded with walkcap: a pmd pico flexx time-of-flight camera and
an Xsens MTi IMU on the {study.imu_placement}. Each trial is one walk over a course of level
ground, stairs and ramps; the operator keys the locomotion mode live. Trials from
walkcap's simulated devices say so in their motion.json (ManufacturersModelName).

## Modes

LG level ground, US up stairs, DS down stairs, UR up ramp, DR down ramp.

## The two references

- locomotion: the mode the operator keyed live (undos applied), in each trial's
  events.tsv (trial_type `mode`; every undone or superseded change stays, as the audit
  trail).
- terrain: what the camera image shows (the simulator's truth for mock sessions, else
  labels made offline), in derivatives/walkcap/ per camera frame.

## Layout

- sub-<subject>/motion/: per trial (task-<condition>_run-<trial>) the IMU as the tracking
  system `imu` (acceleration, rate of turn, orientation quaternion, a LATENCY channel
  with each sample's exact time; samples the IMU produced and the file lacks are n/a
  rows), and events.tsv (label changes, markers, device events; onsets in seconds from
  the first IMU sample).
- sub-<subject>/sub-<subject>_scans.tsv: acq_time of each trial's first IMU sample.
- participants.tsv: age, sex, height, weight, amputee, side, residual limb.
- sourcedata/: each original walkcap recording (MCAP, with its depth frames) and its
  journal, byte for byte.
- derivatives/walkcap/: CNN probabilities, fused decisions and terrain features per frame.
{DEIDENTIFIED if deidentified else ""}"""


DEIDENTIFIED = "- De-identified: dates shifted, free text (notes, marker notes) left out.\n"


# ---- files ----------------------------------------------------------------------------


def _read_tsv(path: Path, key: str) -> dict[str, dict]:
    if not path.is_file():
        return {}
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise CaptureError(f"{path}: cannot read: {e}") from None
    if not lines:
        return {}
    header = lines[0].split("\t")
    if key not in header:
        raise CaptureError(f"{path}: no {key} column; not a walkcap BIDS table")
    rows = {}
    for line in lines[1:]:
        if line.strip():
            row = dict(zip(header, line.split("\t"), strict=False))
            rows[row[key]] = row
    return rows


def _read_json(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise CaptureError(f"{path}: cannot read: {e}") from None
    return value if isinstance(value, dict) else {}


def _text(path: Path, text: str) -> None:
    _whole(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _json(path: Path, value: dict) -> None:
    _text(path, json.dumps(value, indent=2, ensure_ascii=False) + "\n")


def _copy(src: Path, dst: Path) -> Path:
    return _whole(dst, lambda tmp: shutil.copyfile(src, tmp))


def _whole(path: Path, write) -> Path:
    """Written beside, renamed into place: a full disk leaves no half file under the name."""
    tmp = path.with_name(f".{path.name}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise CaptureError(f"{path}: not written ({e.strerror or e})") from None
    return path
