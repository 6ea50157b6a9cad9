"""Replay keeps a recording's IMU in compact columns and writes the samples from them in
sample-time order: the same samples, in the same order, as sorting the samples in memory."""

import numpy as np

import capture.corpus.replay as R
from capture.recording import topics as T
from capture.recording.reader import imu_sample, open_recording
from capture.recording.writer import Recorder
from devices.frames import ImuSample


def _sample(k: int, t_ns: int, oriented: bool = True, rate: bool = True) -> ImuSample:
    angle = 0.01 * k
    return ImuSample(
        host_time_ns=t_ns + 3_000_000,
        time_ns=t_ns,
        packet_counter=k,
        quaternion=np.array([np.cos(angle), np.sin(angle), 0.0, 0.0]) if oriented else None,
        acceleration=np.array([0.0, 0.0, 9.81]),
        rate_of_turn=np.array([0.1 * k, 0.0, 0.0]) if rate else None,
    )


def _recording_out_of_order(path):
    """IMU samples at 100 Hz, some written after later ones (a host that delivered them
    late), one pair at the same time, some without an orientation or a rate of turn."""
    times = [k * 10_000_000 for k in range(200)]
    written = list(range(200))
    for a, b in ((5, 9), (50, 51), (120, 140), (199, 180)):
        written[a], written[b] = written[b], written[a]
    times[61] = times[60]  # the same sample time: the file's order decides
    with Recorder(path, metadata={}) as rec:
        for k in written:
            rec.write_imu(_sample(k, times[k], oriented=k % 17 != 3, rate=k % 13 != 4))
    return path


def test_the_imu_read_again_comes_in_the_order_a_sort_in_memory_gives(tmp_path):
    path = _recording_out_of_order(tmp_path / "imu.mcap")
    in_file = [imu_sample(m.data) for m in open_recording(path).messages([T.IMU])]
    by_time = sorted(in_file, key=lambda s: s.time_ns)  # stable: file order among equals
    assert [s.packet_counter for s in in_file] != [s.packet_counter for s in by_time]

    imu, labels, events = R.recorded_compact(open_recording(path))
    assert labels == [] and isinstance(events, list)
    again = list(imu.in_order())
    assert [s.packet_counter for s in again] == [s.packet_counter for s in by_time]
    assert [s.time_ns for s in again] == list(imu.times_ns)
    for a, b in zip(again, by_time):
        _same(a, b)

    times, quats, rates = imu.orientations
    oriented = [s for s in by_time if s.quaternion is not None]
    assert len(oriented) < len(by_time)
    assert list(times) == [s.time_ns for s in oriented]
    np.testing.assert_array_equal(quats, np.array([s.quaternion for s in oriented]))
    expected = [s.rate_of_turn if s.rate_of_turn is not None else [np.nan] * 3 for s in oriented]
    np.testing.assert_array_equal(rates, np.array(expected))


def _same(a: ImuSample, b: ImuSample) -> None:
    for name in ("host_time_ns", "time_ns", "packet_counter", "sample_time_fine", "extra"):
        assert getattr(a, name) == getattr(b, name)
    for name in ("quaternion", "acceleration", "rate_of_turn"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == y.dtype == np.float64
            np.testing.assert_array_equal(x, y)


def test_a_sample_comes_back_as_it_went_in_even_one_the_columns_do_not_fit():
    columns = R.ImuColumns()
    odd = _sample(3, 30_000_000)
    odd.extra = {"free_acceleration": [0.1, 0.2, 0.3]}
    short = ImuSample(host_time_ns=5, quaternion=np.array([1.0, 0.0]))  # not a quaternion
    given = [_sample(0, 0), _sample(1, 10, oriented=False, rate=False), odd, short]
    given.append(ImuSample(host_time_ns=7))
    for s in given:
        columns.add(s)
    assert len(columns) == 5 and set(columns.whole()) == {2, 3}
    for k, s in enumerate(given):
        back = columns.sample(k)
        assert back.extra == s.extra
        for name in ("host_time_ns", "time_ns", "packet_counter", "status_word"):
            assert getattr(back, name) == getattr(s, name)
        for name in ("quaternion", "acceleration", "rate_of_turn"):
            x, y = getattr(back, name), getattr(s, name)
            assert (x is None) == (y is None) and (x is None or np.array_equal(x, y))


def test_what_replay_holds_of_the_imu_is_about_two_hundred_bytes_a_sample(tmp_path):
    """No sample objects stay in memory (nearly 800 bytes each): arrays alone."""
    path = _recording_out_of_order(tmp_path / "imu.mcap")
    imu, _, _ = R.recorded_compact(open_recording(path))
    arrays = [imu.order, imu.times_ns, *imu.orientations]
    assert all(isinstance(a, np.ndarray) and a.dtype != object for a in arrays)
    assert not imu.samples.whole()
    held = imu.samples.nbytes + sum(a.nbytes for a in arrays)
    assert held / len(imu.order) <= 256  # an ImuSample object alone takes nearly 800
