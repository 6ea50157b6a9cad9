"""The export's IMU columns keep every gap a sample has: a missing field, a missing vector,
a missing component."""

from __future__ import annotations

import numpy as np
import pandas as pd

from capture.corpus import export
from capture.corpus.imu_columns import ImuColumns


def test_gaps_stay_gaps_and_times_fall_back_to_arrival():
    imu = ImuColumns(export._IMU_FIELDS)
    full = {
        "time_ns": 10,
        "host_time_ns": 12,
        "packet_counter": 7,
        "sample_time_fine": 70,
        "quaternion": [1.0, 0.0, 0.0, 0.0],
        "acceleration": [0.0, 0.0, 9.8],
        "rate_of_turn": [0.1, 0.2, 0.3],
        "status_word": 3,
    }
    for _ in range(1500):  # past the first block of rows
        imu.add(full)
    imu.add({"host_time_ns": 20, "acceleration": [1.0, None, 2.0]})
    assert len(imu) == 1501
    times = imu.times()
    assert times[0] == 10 and times[-1] == 20
    cols = export._imu_columns(imu, times, None, 0)
    assert list(cols["packet_counter"][-2:]) == [7, pd.NA]
    assert cols["status_word"].dtype == "Int64" and cols["host_time_ns"][-1] == 20
    assert np.isnan(cols["qw"][-1]) and cols["qw"][0] == 1.0
    assert cols["acc_x"][-1] == 1.0 and np.isnan(cols["acc_y"][-1]) and cols["acc_z"][-1] == 2.0
    assert cols["gyr_z"][0] == 0.3
