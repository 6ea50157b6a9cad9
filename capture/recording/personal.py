"""Personal data in a recording: what it is, where it is kept, and how a shared copy reduces it.

`PERSONAL_FIELDS` is the one list of every field that is personal or identifying: what it
holds, where walkcap stores it, who needs it, and what a copy made for sharing does with it
(docs/recordings.md#personal-data shows the same list; a test keeps the two equal).

`ShareRules` is what a study chooses for copies it shares (`walkcap share`, the BIDS export):
free text (notes, operator, marker text) dropped, replaced or kept; body data kept,
coarsened or dropped; dates shifted by whole days, one offset per subject or per study,
derived from the study's secret (the same secret gives the same offset in every run and
every file) or given explicitly. The functions below apply the rules to plain values
(metadata records, events, Unix times, file names) and touch no file.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import re
from dataclasses import dataclass, field, replace

from capture.errors import CaptureError

# What a field is (the kind decides which rule applies to it).
IDENTIFIER, BODY, HEALTH, FREE_TEXT, PERSON, TIME = (
    "identifier",
    "body",
    "health",
    "free text",
    "person",
    "time",
)


@dataclass(frozen=True)
class PersonalField:
    """One personal or identifying field."""

    name: str  # as the docs' table names it: record.key, a topic's field, a file name
    kind: str  # IDENTIFIER | BODY | HEALTH | FREE_TEXT | PERSON | TIME
    what: str  # what it holds
    stored: tuple[str, ...]  # every place walkcap keeps it
    needed_by: str  # who needs it
    shared: str  # what a shared copy holds (the default ShareRules)


PERSONAL_FIELDS: tuple[PersonalField, ...] = (
    PersonalField(
        "session.subject",
        IDENTIFIER,
        "the subject's pseudonymous id ([session] subject_pattern, never a name)",
        (
            "metadata session and derivation",
            "file names",
            "walkcap info",
            "export: every table",
            "last_session.json",
            "tui.log",
        ),
        "everyone: it groups a subject's trials; only the study's key list links it to a person",
        "kept",
    ),
    PersonalField(
        "session.age",
        BODY,
        "age in years",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (the paper's subject table)",
        "kept (coarsen: 5-year bands, 90 and over as 90)",
    ),
    PersonalField(
        "session.sex",
        BODY,
        "female, male or other",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (the paper's subject table)",
        "kept",
    ),
    PersonalField(
        "session.height_m",
        BODY,
        "height in metres",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (the camera's height above ground)",
        "kept (coarsen: to 0.05 m)",
    ),
    PersonalField(
        "session.weight_kg",
        BODY,
        "weight in kilograms",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (the paper's subject table)",
        "kept (coarsen: to 5 kg)",
    ),
    PersonalField(
        "session.amputee",
        HEALTH,
        "whether the subject walks with a prosthesis",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (amputee and able-bodied groups)",
        "kept",
    ),
    PersonalField(
        "session.side",
        HEALTH,
        "the amputated side (left or right)",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (which thigh carries the sensors)",
        "kept",
    ),
    PersonalField(
        "session.residual_limb_cm",
        HEALTH,
        "residual limb length in centimetres",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the analysis (the paper's subject table)",
        "kept (coarsen: to 5 cm)",
    ),
    PersonalField(
        "session.notes",
        FREE_TEXT,
        "the form's Notes: free text about the trial",
        ("metadata session", "walkcap info", "export trials", "last_session.json"),
        "the lab running the study",
        "dropped",
    ),
    PersonalField(
        "session.operator",
        PERSON,
        "who ran the session (the form's Operator, [session] operator)",
        (
            "metadata session",
            "walkcap.toml attachment",
            "walkcap info",
            "export trials",
            "last_session.json",
            "the configuration file",
        ),
        "the lab running the study",
        "dropped",
    ),
    PersonalField(
        "/events marker text",
        FREE_TEXT,
        "the note typed with a marker (live key m, or in replay)",
        ("/events", "journal", "export events"),
        "the lab; the analysis reads the marker's time",
        "replaced by 'marker' (the time is kept)",
    ),
    PersonalField(
        "/lsl/NAME",
        FREE_TEXT,
        "other programs' streams recorded into the trial ([lsl] record): marker streams may "
        "carry text",
        ("/lsl/NAME", "export"),
        "the analysis of those devices",
        "kept as recorded (another program's data: record only what may be shared)",
    ),
    PersonalField(
        "file names",
        TIME,
        "the date and time a trial started (<subject>_<condition>_t<NN>_<YYYYmmdd-HHMMSS>)",
        (
            "the recording's and journal's names",
            "metadata recording.journal, derivation.source_name, software.replay_of, "
            "corrections.source, recovery.source",
            "export: every table's file column",
        ),
        "the lab (finding a session's files)",
        "<subject>_<condition>_t<NN>.mcap, no time",
    ),
    PersonalField(
        "recording.unix_offset_ns",
        TIME,
        "the offset from the session clock to Unix time: the date and time of every message",
        (
            "metadata recording",
            "walkcap info",
            "export: unix_time_ns columns, trials start/end_unix_time_ns",
        ),
        "the lab (matching other devices' files by clock time)",
        "shifted by the subject's or study's whole-day offset",
    ),
    PersonalField(
        "other Unix times",
        TIME,
        "when the file was closed, its attachments written, its corrections saved",
        (
            "metadata recording_end.closed_unix_time_ns",
            "metadata corrections.written",
            "attachment create times",
            "journal start unix_time_ns",
        ),
        "nobody beyond the lab",
        "shifted by the same offset",
    ),
    PersonalField(
        "/imu extra.utc_time",
        TIME,
        "the IMU's UTC date and time, when the IMU is configured to send it",
        ("/imu", "export imu"),
        "the lab (GNSS models: the device's own clock)",
        "shifted by the same offset",
    ),
)

# The session record's fields by kind (the rest of it is not personal).
BODY_NUMBERS = ("age", "height_m", "weight_kg", "residual_limb_cm")
# Coarsening: a number to a multiple of its step (age: the band's lower bound).
COARSEN_STEP = {"age": 5, "height_m": 0.05, "weight_kg": 5.0, "residual_limb_cm": 5.0}
AGE_CAP = 90  # ages over 89 identify: shared as 90
AMPUTATION = ("amputee", "side")

# Rule values.
KEEP, DROP, REPLACE, COARSEN = "keep", "drop", "replace", "coarsen"
BY_SUBJECT, BY_STUDY = "subject", "study"
TEXT_RULES = (DROP, REPLACE, KEEP)
BODY_RULES = (KEEP, COARSEN, DROP)
FIELD_RULES = (KEEP, DROP)
DATE_RULES = (BY_SUBJECT, BY_STUDY, KEEP)

DAY_NS = 86_400 * 10**9
MARKER_TEXT = "marker"  # what a marker without a note says
# A file name's time stamp (capture.live.trials.trial_file): _YYYYmmdd-HHMMSS
_FILE_TIME = re.compile(r"_\d{8}-\d{6}(?=[._]|$)")
_ISO_DATETIME = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?([+-]\d{2}:?\d{2}|Z)?$")


class RulesError(CaptureError, ValueError):
    """Rules that cannot be applied (a shift with no secret, an unknown rule): one line."""


@dataclass(frozen=True)
class ShareRules:
    """What a copy made for sharing keeps of each personal field."""

    notes: str = DROP  # drop | replace | keep
    operator: str = DROP  # drop | replace | keep
    markers: str = REPLACE  # marker text: replace ("marker") | drop ("") | keep
    replacement: str = "[removed]"  # what `replace` puts in notes and operator
    body: str = KEEP  # age, height, weight, residual limb: keep | coarsen | drop
    sex: str = KEEP  # keep | drop
    amputation: str = KEEP  # amputee and side: keep | drop
    dates: str = BY_SUBJECT  # one offset per subject | per study | keep the real dates
    secret: str = ""  # the study's secret the offsets derive from
    shift_days: int | None = None  # an explicit offset in days (every file), not derived
    max_shift_days: int = 3650  # derived offsets: 1 to this many days back

    def problems(self) -> list[str]:
        out = []
        for name, allowed in (
            ("notes", TEXT_RULES),
            ("operator", TEXT_RULES),
            ("markers", TEXT_RULES),
            ("body", BODY_RULES),
            ("sex", FIELD_RULES),
            ("amputation", FIELD_RULES),
            ("dates", DATE_RULES),
        ):
            if getattr(self, name) not in allowed:
                out.append(f"{name}: one of {', '.join(allowed)}, not {getattr(self, name)!r}")
        if self.max_shift_days < 1:
            out.append("max_shift_days: at least 1")
        if self.dates != KEEP and self.shift_days is None and not self.secret:
            out.append(
                "dates: shifting them needs the study's secret ([share] secret) or an "
                "explicit number of days (--shift-days); the same secret gives the same "
                "offsets every time"
            )
        return out

    def check(self) -> ShareRules:
        problems = self.problems()
        if problems:
            raise RulesError("; ".join(problems))
        return self

    def with_changes(self, **changes) -> ShareRules:
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def describe(self) -> dict:
        """The rules as a shared copy records them (never the secret)."""
        return {
            "notes": self.notes,
            "operator": self.operator,
            "markers": self.markers,
            "body": self.body,
            "body_steps": dict(COARSEN_STEP) if self.body == COARSEN else {},
            "sex": self.sex,
            "amputation": self.amputation,
            "dates": "explicit offset" if self.shift_days is not None else self.dates,
        }


# ---- dates ---------------------------------------------------------------------------------


def date_offset_days(rules: ShareRules, subject: str) -> int:
    """The whole number of days every date of `subject`'s files moves by (negative: back).

    Derived offsets are an HMAC of the study's secret and the subject id (or the study):
    reproducible, the same for every file of a subject, and not computable without the
    secret. Whole days keep the time of day and the weekday cycle's distance between trials.
    """
    if rules.dates == KEEP:
        return 0
    if rules.shift_days is not None:
        return int(rules.shift_days)
    if not rules.secret:
        raise RulesError(ShareRules.problems(rules)[-1])
    key = f"walkcap date shift:{subject if rules.dates == BY_SUBJECT else 'study'}"
    digest = hmac.new(rules.secret.encode(), key.encode(), hashlib.sha256).digest()
    return -(1 + int.from_bytes(digest[:8], "big") % rules.max_shift_days)


def date_offset_ns(rules: ShareRules, subject: str) -> int:
    return date_offset_days(rules, subject) * DAY_NS


def shift_unix_ns(unix_ns: int | None, offset_ns: int) -> int | None:
    """A Unix time (ns) moved by the offset; None stays None."""
    return None if unix_ns is None else int(unix_ns) + int(offset_ns)


def shift_iso(text: str, offset_ns: int) -> str:
    """An ISO date-time text moved by the offset (whole days); other text unchanged."""
    import datetime as dt

    if not isinstance(text, str) or not _ISO_DATETIME.match(text):
        return text
    try:
        when = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return text
    shifted = when + dt.timedelta(microseconds=offset_ns // 1000)
    return shifted.isoformat(timespec="seconds")


def shift_utc_fields(utc: list | tuple, offset_ns: int) -> list:
    """The IMU's UtcTime (ns, year, month, day, hour, minute, second, flags) moved by the
    offset (whole days: the date changes, the time of day stays)."""
    import datetime as dt

    ns, year, month, day, hour, minute, second, *flags = utc
    try:
        when = dt.datetime(int(year), int(month), int(day), int(hour), int(minute), int(second))
    except (ValueError, TypeError):
        return list(utc)  # an invalid UTC (no GNSS fix) says nothing
    when += dt.timedelta(days=offset_ns // DAY_NS)
    return [ns, when.year, when.month, when.day, when.hour, when.minute, when.second, *flags]


# ---- names ---------------------------------------------------------------------------------


def strip_file_time(name: str) -> str:
    """A file name without its time stamp: S01_indoor_t01_20261122-101500.replay.mcap ->
    S01_indoor_t01.replay.mcap. Other text is returned unchanged."""
    return _FILE_TIME.sub("", name) if isinstance(name, str) else name


def shared_name(subject: str, condition: str, trial: int | None) -> str:
    """The file name of a shared copy: the trial, no time."""
    number = f"t{trial:02d}" if trial is not None else "t00"
    return f"{subject or 'unknown'}_{condition or 'unknown'}_{number}.mcap"


# ---- values --------------------------------------------------------------------------------


def _text(value: str, rule: str, replacement: str) -> str:
    if rule == KEEP or not value:
        return value
    return replacement if rule == REPLACE else ""


def _coarsen(name: str, value):
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    step = COARSEN_STEP[name]
    if name == "age":
        return min(AGE_CAP, int(value) // step * step)
    return round(round(value / step) * step, 2)


def reduce_session(session: dict, rules: ShareRules) -> tuple[dict, list[str]]:
    """The "session" metadata record (the form, operator) as a shared copy holds it, and
    what was removed or changed (one phrase per field, e.g. "notes dropped")."""
    out, removed = dict(session), []
    for name, rule in (("notes", rules.notes), ("operator", rules.operator)):
        value = out.get(name)
        if isinstance(value, str) and value:
            new = _text(value, rule, rules.replacement)
            if new != value:
                out[name] = new
                removed.append(f"{name} {'replaced' if rule == REPLACE else 'dropped'}")
    for name in BODY_NUMBERS:
        value = out.get(name)
        if value is None:
            continue
        if rules.body == DROP:
            out[name] = None
            removed.append(f"{name} dropped")
        elif rules.body == COARSEN:
            new = _coarsen(name, value)
            if new != value:
                out[name] = new
            removed.append(f"{name} coarsened to {COARSEN_STEP[name]:g}")
    if rules.sex == DROP and out.get("sex"):
        out["sex"] = ""
        removed.append("sex dropped")
    if rules.amputation == DROP:
        if "amputee" in out and out["amputee"] is not None:
            out["amputee"] = None
            removed.append("amputee dropped")
        if out.get("side"):
            out["side"] = ""
            removed.append("side dropped")
    return out, removed


def reduce_event(entry: dict, rules: ShareRules) -> dict:
    """An /events entry (capture.recording.topics.event_json) as a shared copy holds it:
    an operator's marker keeps its time, its text follows `rules.markers`."""
    if entry.get("device") != "operator" or rules.markers == KEEP:
        return entry
    out = dict(entry)
    out["message"] = MARKER_TEXT if rules.markers == REPLACE else ""
    details = dict(out.get("details") or {})
    for key in ("note", "text"):
        details.pop(key, None)
    out["details"] = details
    return out


def is_personal_event(entry: dict) -> bool:
    """Whether an /events entry carries the operator's text (markers and notes)."""
    return entry.get("device") == "operator"


# The metadata records and keys that hold file names (with their times).
_NAME_KEYS = {
    "recording": ("journal",),
    "derivation": ("source_name",),
    "software": ("replay_of",),
    "corrections": ("source",),
    "recovery": ("source", "journal"),
}
_UNIX_KEYS = {"recording": ("unix_offset_ns",), "recording_end": ("closed_unix_time_ns",)}
_ISO_KEYS = {"corrections": ("written",)}


@dataclass
class Reduced:
    """A metadata record as a shared copy holds it, and what changed in it."""

    name: str
    values: dict
    removed: list[str] = field(default_factory=list)


def reduce_metadata(name: str, values: dict, rules: ShareRules, offset_ns: int) -> Reduced:
    """One metadata record (typed values, as capture.recording.reader gives them) as a
    shared copy holds it: the session's personal fields by the rules, file names without
    their times, Unix times and date-times moved by `offset_ns`."""
    if name == "session":
        out, removed = reduce_session(values, rules)
    else:
        out, removed = dict(values), []
    for key in _NAME_KEYS.get(name, ()):
        if isinstance(out.get(key), str) and strip_file_time(out[key]) != out[key]:
            out[key] = strip_file_time(out[key])
            removed.append(f"{name}.{key}: time removed from the file name")
    for key in _UNIX_KEYS.get(name, ()):
        if isinstance(out.get(key), int) and offset_ns:
            out[key] = shift_unix_ns(out[key], offset_ns)
            removed.append(f"{name}.{key} shifted")
    for key in _ISO_KEYS.get(name, ()):
        if isinstance(out.get(key), str) and offset_ns:
            out[key] = shift_iso(out[key], offset_ns)
            removed.append(f"{name}.{key} shifted")
    return Reduced(name, out, removed)


_OPERATOR_LINE = re.compile(r'^(\s*operator\s*=\s*)(".*?(?<!\\)"|\'.*?\')(.*)$', re.M)


def reduce_config_text(text: str, rules: ShareRules) -> str:
    """The walkcap.toml attachment with [session] operator following `rules.operator`."""
    if rules.operator == KEEP:
        return text
    new = "" if rules.operator == DROP else rules.replacement.replace('"', "'")
    return _OPERATOR_LINE.sub(lambda m: f'{m.group(1)}"{new}"{m.group(3)}', text)


def unix_day(unix_ns: int) -> str:
    """The UTC date of a Unix time, for reports (YYYY-MM-DD)."""
    import datetime as dt

    return dt.datetime.fromtimestamp(math.floor(unix_ns / 1e9), dt.UTC).date().isoformat()


def fields_markdown() -> str:
    """PERSONAL_FIELDS as the table docs/recordings.md shows (a test keeps them equal)."""
    lines = [
        "| field | kind | what | stored in | needed by | in a shared copy |",
        "|---|---|---|---|---|---|",
    ]
    for f in PERSONAL_FIELDS:
        stored = "; ".join(f.stored)
        lines.append(
            f"| `{f.name}` | {f.kind} | {f.what} | {stored} | {f.needed_by} | {f.shared} |"
        )
    return "\n".join(lines) + "\n"


# ---- notes ---------------------------------------------------------------------------------

NOTES_HELP = (
    "Notes: about the trial (shoes, prosthesis, socket, weather, what went wrong); "
    "never names, dates of birth or places: notes go into every file"
)
_CAP = r"[A-ZÄÖÜ][a-zäöüß]+(?:-[A-ZÄÖÜ][a-zäöüß]+)?"
_TITLES = r"(?:Mr|Mrs|Ms|Miss|Dr|Prof|Herr|Frau|Hr|Fr)\.?"
_NAME = re.compile(rf"\b{_CAP}\s+{_CAP}\b|\b{_TITLES}\s+{_CAP}\b")
_DATE = re.compile(
    r"\b\d{1,2}[./-]\d{1,2}[./-](?:\d{2}|\d{4})\b|\b(?:19|20)\d{2}-\d{1,2}-\d{1,2}\b"
    r"|\b(?:born|dob|d\.o\.b|geb|geboren|birthday)\b",
    re.IGNORECASE,
)
_PLACE = re.compile(
    r"\b(?i:from|in|at|lives|aus)\s+(?i:the\s+)?" + _CAP + r"\b"
    r"|(?i:\b\w*(?:klinik|clinic|hospital|krankenhaus|ward|street|straße|strasse|road|avenue)\b)"
    r"|\b\d{5}\b"
)


def note_warnings(text: str) -> list[str]:
    """What in a note looks personal: a name (two capitalised words in a row, or a title
    and a capitalised word), a date of birth (a date, or words such as "born"), a place
    ("from" or "in" and a capitalised word, words such as clinic, ward or street, a postal
    code). A heuristic that errs towards warning: it catches the common cases, not every
    one, and it never changes the note."""
    found = []
    if _NAME.search(text or ""):
        found.append("a name")
    if _DATE.search(text or ""):
        found.append("a date of birth")
    if _PLACE.search(text or ""):
        found.append("a place")
    return found
