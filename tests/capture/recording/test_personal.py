"""The personal fields and the rules a copy made for sharing follows (pure functions)."""

import pytest

from capture.recording import personal as P
from capture.recording.personal import PERSONAL_FIELDS, ShareRules

SESSION = {
    "subject": "S01",
    "height_m": 1.78,
    "weight_kg": 81.3,
    "age": 37,
    "sex": "female",
    "amputee": True,
    "side": "left",
    "residual_limb_cm": 31.0,
    "condition": "indoor",
    "trial": 2,
    "notes": "Anna Schmidt, came from ward 3",
    "operator": "Jane Doe",
}


def test_every_session_field_that_describes_a_person_is_listed():
    listed = {f.name for f in PERSONAL_FIELDS}
    for key in ("subject", "age", "sex", "height_m", "weight_kg", "amputee", "side"):
        assert f"session.{key}" in listed
    for key in ("residual_limb_cm", "notes", "operator"):
        assert f"session.{key}" in listed
    assert "recording.unix_offset_ns" in listed and "file names" in listed
    assert all(f.stored and f.needed_by and f.shared for f in PERSONAL_FIELDS)
    assert len(listed) == len(PERSONAL_FIELDS)


def test_default_rules_drop_free_text_and_keep_body_data():
    out, removed = P.reduce_session(SESSION, ShareRules(secret="s"))
    assert out["notes"] == "" and out["operator"] == ""
    assert {k: out[k] for k in P.BODY_NUMBERS} == {k: SESSION[k] for k in P.BODY_NUMBERS}
    assert out["amputee"] is True and out["side"] == "left"
    assert "notes dropped" in removed and "operator dropped" in removed
    assert SESSION["notes"].startswith("Anna")  # the input is not modified


def test_replace_coarsen_and_drop():
    rules = ShareRules(notes="replace", body="coarsen", sex="drop", amputation="drop", secret="s")
    out, removed = P.reduce_session(SESSION, rules)
    assert out["notes"] == "[removed]"
    assert (out["age"], out["height_m"], out["weight_kg"], out["residual_limb_cm"]) == (
        35,
        1.8,
        80.0,
        30.0,
    )
    assert out["sex"] == "" and out["amputee"] is None and out["side"] == ""
    assert "notes replaced" in removed
    dropped, _ = P.reduce_session(SESSION, ShareRules(body="drop", secret="s"))
    assert all(dropped[k] is None for k in P.BODY_NUMBERS)
    assert P.reduce_session({**SESSION, "age": 95}, rules)[0]["age"] == 90


def test_date_offsets_are_reproducible_per_subject_and_per_study():
    rules = ShareRules(secret="study secret")
    a = P.date_offset_days(rules, "S01")
    assert a == P.date_offset_days(ShareRules(secret="study secret"), "S01")
    assert -rules.max_shift_days <= a <= -1
    assert P.date_offset_days(ShareRules(secret="another"), "S01") != a
    others = {P.date_offset_days(rules, f"S{i:02d}") for i in range(2, 12)}
    assert len(others | {a}) > 1  # per subject: subjects differ
    study = ShareRules(secret="study secret", dates="study")
    assert P.date_offset_days(study, "S01") == P.date_offset_days(study, "P07")
    assert P.date_offset_days(ShareRules(shift_days=-400), "S01") == -400
    assert P.date_offset_days(ShareRules(dates="keep"), "S01") == 0
    assert P.date_offset_ns(ShareRules(shift_days=-2), "S01") == -2 * 86_400 * 10**9


def test_shifting_without_a_secret_is_refused():
    with pytest.raises(P.RulesError, match="secret"):
        ShareRules().check()
    with pytest.raises(P.RulesError, match="secret"):
        P.date_offset_days(ShareRules(), "S01")
    with pytest.raises(P.RulesError, match="notes"):
        ShareRules(notes="blur", secret="s").check()
    ShareRules(dates="keep").check()


def test_times_move_by_whole_days():
    day = P.DAY_NS
    assert P.shift_unix_ns(1_700_000_000 * 10**9, -3 * day) == 1_700_000_000 * 10**9 - 3 * day
    assert P.shift_unix_ns(None, day) is None
    assert P.shift_iso("2026-11-22T10:15:00", -day) == "2026-11-21T10:15:00"
    assert P.shift_iso("not a date", -day) == "not a date"
    assert P.shift_utc_fields([5, 2026, 3, 1, 10, 15, 0, 7], -day) == [5, 2026, 2, 28, 10, 15, 0, 7]
    assert P.shift_utc_fields([0, 0, 0, 0, 0, 0, 0, 0], -day) == [0, 0, 0, 0, 0, 0, 0, 0]


def test_file_names_lose_their_time():
    assert P.strip_file_time("S01_indoor_t01_20261122-101500.mcap") == "S01_indoor_t01.mcap"
    assert (
        P.strip_file_time("S01_indoor_t01_20261122-101500_corrected.mcap")
        == "S01_indoor_t01_corrected.mcap"
    )
    assert (
        P.strip_file_time("S01_indoor_t01_20261122-101500.mcap.journal.jsonl")
        == "S01_indoor_t01.mcap.journal.jsonl"
    )
    assert P.shared_name("S01", "indoor", 3) == "S01_indoor_t03.mcap"


def test_metadata_records_are_reduced():
    offset = -10 * P.DAY_NS
    rec = P.reduce_metadata(
        "recording",
        {
            "id": "x",
            "unix_offset_ns": 1_000 * P.DAY_NS,
            "journal": "S01_a_t01_20261122-101500.mcap.journal.jsonl",
        },
        ShareRules(secret="s"),
        offset,
    )
    assert rec.values["unix_offset_ns"] == 990 * P.DAY_NS
    assert rec.values["journal"] == "S01_a_t01.mcap.journal.jsonl"
    assert rec.removed
    d = P.reduce_metadata(
        "derivation",
        {"source_name": "S01_a_t01_20261122-101500.mcap"},
        ShareRules(secret="s"),
        offset,
    )
    assert d.values["source_name"] == "S01_a_t01.mcap"
    c = P.reduce_metadata(
        "corrections", {"written": "2026-11-22T10:15:00"}, ShareRules(secret="s"), offset
    )
    assert c.values["written"] == "2026-11-12T10:15:00"
    devices = {"camera": "royale", "serial": "0005-1234"}
    assert P.reduce_metadata("devices", devices, ShareRules(secret="s"), offset).values == devices


def test_marker_text_is_replaced_and_other_events_kept():
    marker = {
        "time_ns": 5,
        "device": "operator",
        "kind": "marker",
        "message": "Anna fell",
        "details": {},
    }
    assert P.reduce_event(marker, ShareRules(secret="s"))["message"] == "marker"
    assert P.reduce_event(marker, ShareRules(markers="drop", secret="s"))["message"] == ""
    assert P.reduce_event(marker, ShareRules(markers="keep", secret="s")) == marker
    fault = {"time_ns": 5, "device": "imu", "kind": "gap", "message": "3 packets", "details": {}}
    assert P.reduce_event(fault, ShareRules(secret="s")) is fault


def test_the_attached_configuration_loses_the_operator():
    text = (
        '[session]\nrecordings = "recordings"\noperator = "Jane Doe"\n[share]\noperator = "drop"\n'
    )
    out = P.reduce_config_text(text, ShareRules(secret="s"))
    assert "Jane" not in out and 'operator = ""' in out and 'recordings = "recordings"' in out
    assert '[share]\noperator = "drop"' in out  # another section's key of the same name
    replaced = P.reduce_config_text(text, ShareRules(operator="replace", secret="s"))
    assert 'operator = "[removed]"' in replaced
    assert P.reduce_config_text(text, ShareRules(operator="keep", secret="s")) == text


def test_the_docs_list_the_same_fields():
    from pathlib import Path

    docs = (Path(__file__).parents[3] / "docs" / "recordings.md").read_text()
    assert P.fields_markdown() in docs


def test_rules_come_from_the_share_section_with_changes_on_top():
    from capture.config import Config

    section = Config().share
    section.body, section.secret = "coarsen", "s"
    rules = ShareRules.from_config(section, notes="replace", dates=None)
    assert (rules.body, rules.notes, rules.dates, rules.secret) == (
        "coarsen",
        "replace",
        "subject",
        "s",
    )
    assert ShareRules.from_config(Config().share) == ShareRules()


def test_the_study_secret_never_goes_into_a_recording():
    from capture.config import Config
    from capture.live.trials import trial_attachments

    config = Config()
    config.share.secret = "the study's own secret"
    toml = trial_attachments(config, {})["walkcap.toml"].decode()
    assert "the study's own secret" not in toml and "[share]" in toml
