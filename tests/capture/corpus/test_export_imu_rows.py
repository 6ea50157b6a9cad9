"""The export's IMU rows: gathered in flat arrays, the table a list of samples would give."""

import numpy as np

from capture.corpus import export


def test_imu_rows_keep_every_value_and_every_gap():
    rows = export._ImuRows()
    rows.add(
        {
            "time_ns": 10,
            "host_time_ns": 12,
            "packet_counter": 65535,
            "sample_time_fine": 2**40,
            "quaternion": [1.0, 0.0, None, 0.0],
            "acceleration": [0.1, -0.2, 9.81],
            "rate_of_turn": None,
            "status_word": 3,
        }
    )
    rows.add({"host_time_ns": 25, "quaternion": None, "acceleration": [1, 2, 3]})
    assert len(rows) == 2
    assert rows.times().tolist() == [10, 25]  # no sample time: its arrival
    cols = export._imu_columns(rows, rows.times(), 100, 0)
    assert cols["packet_counter"].isna().tolist() == [False, True]
    assert cols["packet_counter"][0] == 65535 and cols["sample_time_fine"][0] == 2**40
    assert cols["status_word"].isna().tolist() == [False, True]
    assert cols["host_time_ns"].tolist() == [12, 25] and cols["unix_time_ns"].tolist() == [110, 125]
    assert cols["qw"][0] == 1.0 and np.isnan(cols["qw"][1]) and np.isnan(cols["qy"]).all()
    assert cols["acc_z"].tolist() == [9.81, 3.0] and np.isnan(cols["gyr_x"]).all()
