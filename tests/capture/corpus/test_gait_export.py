"""The gait table of `walkcap export`, in every format, and the gait rows of BIDS events."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.io import loadmat

from capture.corpus import bids_trial as BT
from capture.corpus import export
from devices.frames import GaitEvent
from tests.recording_fixtures import T0, write_recording

EVENTS = [
    GaitEvent(T0 + 300_000_000, "heel_contact", "simulator", "US"),
    GaitEvent(T0 + 305_000_000, "heel_contact", "imu"),
    GaitEvent(T0 + 990_000_000, "toe_off", "imu"),
    GaitEvent(T0 + 1_000_000_000, "toe_off", "simulator", "US"),
]


@pytest.fixture(scope="module")
def path(tmp_path_factory):
    p = tmp_path_factory.mktemp("gait") / "S07_indoor_t03.mcap"
    rec = write_recording(p, seconds=1.5, close=False)
    for e in EVENTS:
        rec.write_gait(e)
    rec.close()
    return p


def test_the_gait_table_has_both_sources_in_time_order(path):
    t = export.tables(path)
    gait = t["gait"]
    assert list(gait.columns) == [
        "file", "recording_id", "subject", "condition", "trial",
        "time_ns", "unix_time_ns", "time_s", "event", "source", "mode",
    ]  # fmt: skip
    assert gait["time_ns"].tolist() == [e.time_ns for e in EVENTS]
    assert gait["source"].tolist() == ["simulator", "imu", "imu", "simulator"]
    assert gait["mode"].tolist() == ["US", "", "", "US"]
    # the same origin as the other tables of the file
    frames = t["frames"]
    row = frames.iloc[0]
    np.testing.assert_allclose(
        gait["time_s"], (gait["time_ns"] - row["time_ns"]) * 1e-9 + row["time_s"], atol=1e-9
    )


@pytest.mark.parametrize("fmt", ["parquet", "csv", "mat"])
def test_every_format_writes_the_gait_table(path, tmp_path, fmt):
    export.write(export.tables(path), tmp_path, fmt)
    if fmt == "parquet":
        back = pd.read_parquet(tmp_path / "gait.parquet")
    elif fmt == "csv":
        back = pd.read_csv(tmp_path / "gait.csv", keep_default_na=False)
    else:
        mat = loadmat(tmp_path / "walkcap.mat", simplify_cells=True)
        back = pd.DataFrame({k: mat["gait"][k] for k in ("time_ns", "event", "source")})
    assert back["event"].tolist() == [e.event for e in EVENTS]
    assert back["source"].tolist() == [e.source for e in EVENTS]
    assert back["time_ns"].astype("int64").tolist() == [e.time_ns for e in EVENTS]


def test_bids_events_have_a_row_per_gait_event(path):
    t = export.tables(path)
    rows = [r.split("\t") for r in BT.events_rows(t, T0, T0 + 1_500_000_000)]
    gait = [r for r in rows if r[2] in ("heel_contact", "toe_off")]
    columns = BT.EVENT_COLUMNS
    assert [(r[2], r[columns.index("source")], r[columns.index("mode")]) for r in gait] == [
        ("heel_contact", "simulator", "US"),
        ("heel_contact", "imu", "n/a"),
        ("toe_off", "imu", "n/a"),
        ("toe_off", "simulator", "US"),
    ]
    assert [float(r[0]) for r in gait] == pytest.approx([0.3, 0.305, 0.99, 1.0])
    assert set(BT.events_json()["trial_type"]["Levels"]) >= {"heel_contact", "toe_off"}
