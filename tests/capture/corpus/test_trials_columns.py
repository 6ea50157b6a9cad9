"""The trials table has one set of columns, the same in every corpus and every format."""

import pandas as pd
import pytest
from scipy.io import loadmat

from capture.corpus import export
from capture.live.trials import SubjectInfo
from tests.recording_fixtures import T0, write_trial

LABELS = [(T0, "LG", "operator")]


def simulated_corpus(folder):
    """What `walkcap synth` writes: subject, condition, trial and notes, no software."""
    folder.mkdir()
    for i in (1, 2):
        session = {"subject": "SIM", "condition": "indoor", "trial": i, "notes": "simulated"}
        write_trial(folder / f"SIM_indoor_t{i:02d}.mcap", LABELS, session=session, frames=20)
    return folder


def live_corpus(folder):
    """What a live session writes: the whole form, the operator, a superseded trial, an
    extra field of some other tool, and the software record."""
    folder.mkdir()
    info = SubjectInfo("S07", 1.72, 70.0, 41, "female", True, "left", 22.5, "outdoor", 3)
    session = info.to_metadata() | {
        "operator": "RA1",
        "supersedes": ["a1b2", "c3d4"],
        "weather": {"sky": "clear"},  # not a column: the table's columns are fixed
    }
    software = {"model_hash": "ab" * 32, "model_path": "bundled", "walkcap_version": "0.2.0",
                "fusion_window": 5, "fusion_vote_delay": 1}  # fmt: skip
    write_trial(
        folder / "S07_outdoor_t03.mcap",
        LABELS,
        session=session,
        metadata={"software": software},
        frames=20,
    )
    return folder


@pytest.fixture
def corpora(tmp_path):
    return simulated_corpus(tmp_path / "sim"), live_corpus(tmp_path / "live")


def test_two_corpora_have_the_same_trials_columns_and_types(corpora):
    sim, live = (export.corpus_tables([c])[0]["trials"] for c in corpora)
    assert list(sim.columns) == list(live.columns)
    assert dict(sim.dtypes) == dict(live.dtypes)
    fixed = {f"session_{k}" for k in export.SESSION_COLUMNS} | set(export.SOFTWARE_COLUMNS)
    assert fixed <= set(sim.columns)
    assert "session_supersedes" in sim.columns and "session_weather" not in live.columns
    row = live.iloc[0]
    assert row["session_supersedes"] == "a1b2 c3d4" and row["session_operator"] == "RA1"
    assert row["session_age"] == 41 and bool(row["session_amputee"]) is True
    assert row["fusion_window"] == 5
    first = sim.iloc[0]
    assert first["session_supersedes"] == "" and pd.isna(first["session_height_m"])
    assert pd.isna(first["session_amputee"]) and pd.isna(first["fusion_window"])


@pytest.mark.parametrize("fmt", export.FORMATS)
def test_every_format_writes_the_same_trials_columns(corpora, tmp_path, fmt):
    columns = []
    for i, corpus in enumerate(corpora):
        tables, _ = export.corpus_tables([corpus])
        out = tmp_path / f"out{i}"
        export.write({"trials": tables["trials"]}, out, fmt)
        if fmt == "parquet":
            columns.append(list(pd.read_parquet(out / "trials.parquet").columns))
        elif fmt == "csv":
            columns.append(list(pd.read_csv(out / "trials.csv").columns))
        else:
            struct = loadmat(out / "walkcap.mat")["trials"][0, 0]
            columns.append(list(struct.dtype.names))
    assert columns[0] == columns[1]
    assert "session_supersedes" in columns[0] and "session_operator" in columns[0]
