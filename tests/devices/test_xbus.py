"""Xbus codec: frames, the streaming parser under abuse, MTData2 in every precision."""

import math
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from devices import xbus
from devices.xbus import MID, XbusParser

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def sample_payload(counter: int = 1) -> bytes:
    return xbus.encode_mtdata2(
        {
            "packet_counter": counter,
            "sample_time_fine": 1000 + counter,
            "quaternion": (1.0, 0.0, 0.0, 0.0),
            "acceleration": (0.0, 0.0, 9.81),
            "rate_of_turn": (0.1, -0.2, 0.3),
            "status_word": 3,
        }
    )


def sample_stream(n: int = 3) -> tuple[bytes, list[xbus.Message]]:
    messages = [xbus.Message(MID.MTDATA2, sample_payload(k)) for k in range(n)]
    return b"".join(m.frame() for m in messages), messages


def same(decoded: list[xbus.Message], expected: list[xbus.Message]) -> bool:
    return [(m.mid, m.data) for m in decoded] == [(m.mid, m.data) for m in expected]


# ----------------------------------------------------------------------------- frames


def test_goto_config_frame_matches_the_documented_bytes():
    assert xbus.build(MID.GOTO_CONFIG) == bytes.fromhex("FAFF3000D1")


def test_long_data_uses_the_extended_length():
    frame = xbus.build(MID.MTDATA2, bytes(300))
    assert frame[3] == 0xFF and frame[4:6] == (300).to_bytes(2, "big")
    assert len(frame) == 300 + 7
    assert sum(frame[1:]) % 256 == 0


@FUZZ
@given(mid=st.integers(0, 255), data=st.binary(max_size=xbus.MAX_DATA))
def test_frame_round_trip(mid, data):
    (msg,) = xbus.parse(xbus.build(mid, data))
    assert (msg.mid, msg.data, msg.bid) == (mid, data, 0xFF)


def test_preamble_bytes_inside_data_do_not_confuse_the_parser():
    data = bytes([0xFA, 0xFF, 0x36, 0x02, 0xFA, 0xFA])
    stream = xbus.build(0x36, data) + xbus.build(0x31)
    assert [(m.mid, m.data) for m in xbus.parse(stream)] == [(0x36, data), (0x31, b"")]


# ----------------------------------------------------------------------------- streaming


def test_split_at_every_offset_gives_the_same_messages():
    stream, expected = sample_stream(3)
    for k in range(len(stream) + 1):
        parser = XbusParser()
        got = parser.feed(stream[:k]) + parser.feed(stream[k:])
        assert same(got, expected), k
        assert parser.checksum_errors == parser.resyncs == 0


def test_one_byte_at_a_time():
    stream, expected = sample_stream(4)
    parser = XbusParser()
    got = [m for b in stream for m in parser.feed(bytes([b]))]
    assert same(got, expected)
    assert all(m.mtdata2.values["packet_counter"] == k for k, m in enumerate(got))


def test_a_corrupted_byte_loses_only_its_message_and_is_counted():
    stream, expected = sample_stream(3)
    bad = bytearray(stream)
    first_len = len(expected[0].frame())
    bad[first_len + 10] ^= 0x5A  # inside the second message's data
    parser = XbusParser()
    got = parser.feed(bytes(bad))
    assert same(got, [expected[0], expected[2]])
    assert parser.checksum_errors == 1
    assert parser.resyncs == 1


def test_a_message_cut_short_then_a_good_one():
    stream, expected = sample_stream(2)
    cut = stream[:30] + stream  # a first message truncated mid-way
    parser = XbusParser()
    got = parser.feed(cut) + parser.finish()
    assert same(got[-2:], expected)
    assert parser.discarded_bytes >= 30


def test_finish_recovers_messages_hidden_behind_a_bogus_long_header():
    stream, expected = sample_stream(2)
    # A fake header announcing 2000 bytes swallows what follows until the end of stream.
    parser = XbusParser()
    got = parser.feed(b"\xfa\xff\x36\xff\x07\xd0" + stream)
    assert got == []
    assert same(parser.finish(), expected)


@FUZZ
@given(st.binary(max_size=4000), st.integers(1, 97))
def test_random_bytes_never_raise_and_the_buffer_stays_bounded(data, chunk):
    parser = XbusParser()
    for i in range(0, len(data), chunk):
        parser.feed(data[i : i + chunk])
        assert parser.buffered <= xbus.MAX_DATA + 7 + chunk
    parser.finish()
    assert parser.buffered == 0


@FUZZ
@given(
    garbage=st.binary(max_size=300),
    chunk=st.integers(1, 200),
    mutations=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=4),
)
def test_garbage_and_corruption_then_recovery_on_the_next_good_message(garbage, chunk, mutations):
    good, expected = sample_stream(3)
    corrupted = bytearray(good)
    for pos, value in mutations:  # damage a first copy of the stream
        corrupted[pos % len(corrupted)] = value
    stream = garbage + bytes(corrupted) + good
    parser = XbusParser()
    got = []
    for i in range(0, len(stream), chunk):
        got += parser.feed(stream[i : i + chunk])
    got += parser.finish()
    good_frames = {m.frame() for m in expected}
    bogus = [m for m in got if m.frame() not in good_frames]
    # A frame made of garbage whose checksum happens to match may swallow good bytes:
    # the parser cannot tell. Otherwise the final good stream comes through whole.
    if not bogus:
        assert same(got[-3:], expected)


def test_garbage_between_messages_is_one_resync_and_a_start_mid_stream_none():
    stream, expected = sample_stream(2)
    parser = XbusParser()
    first = expected[0].frame()
    got = parser.feed(first[5:] + first + b"\x00\x01\x02garbage" + stream)
    assert same(got, expected[:1] + expected)
    assert parser.resyncs == 1 and parser.checksum_errors == 0
    assert parser.discarded_bytes == len(first) - 5 + 10


def test_another_bus_id_is_rejected_by_default_and_accepted_when_asked():
    frame = xbus.build(0x31, b"", bid=0x01)
    assert xbus.parse(frame) == []
    parser = XbusParser(bus_id=None)
    assert [m.bid for m in parser.feed(frame)] == [0x01]


# ----------------------------------------------------------------------------- MTData2

REAL_RANGE = {xbus.FLOAT32: 1e6, xbus.FP1220: 2000.0, xbus.FP1632: 30000.0, xbus.FLOAT64: 1e9}
TOLERANCE = {xbus.FP1220: 2**-21, xbus.FP1632: 2**-33}  # half a step of the fixed point


@st.composite
def mtdata2_values(draw):
    precision = draw(st.sampled_from(sorted(REAL_RANGE)))
    limit = REAL_RANGE[precision]
    reals = st.floats(-limit, limit, allow_nan=False, allow_infinity=False)
    names = draw(st.lists(st.sampled_from(sorted(xbus.XDI)), unique=True, min_size=1))
    values = {}
    for name in names:
        _, kind, count = xbus.OUTPUTS[xbus.XDI[name]]
        if kind == "u16":
            values[name] = draw(st.integers(0, 0xFFFF))
        elif kind == "u32":
            values[name] = draw(st.integers(0, 0xFFFFFFFF))
        elif kind == "utc":  # ns, year, month, day, hour, minute, second, flags
            widths = (32, 16, 8, 8, 8, 8, 8, 8)
            values[name] = tuple(draw(st.integers(0, 2**w - 1)) for w in widths)
        elif name == "rotation_matrix":
            values[name] = tuple(tuple(draw(reals) for _ in range(3)) for _ in range(3))
        elif count == 1:
            values[name] = draw(reals)
        else:
            values[name] = tuple(draw(reals) for _ in range(count))
    system = draw(st.sampled_from(["ENU", "NED", "NWU"]))
    return values, precision, system


def close(a, b, precision) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(close(x, y, precision) for x, y in zip(a, b))
    if isinstance(a, int) and not isinstance(a, bool):
        return a == b
    if precision == xbus.FLOAT32:
        return b == struct.unpack(">f", struct.pack(">f", a))[0]
    if precision == xbus.FLOAT64:
        return b == a
    return math.isclose(a, b, rel_tol=0, abs_tol=TOLERANCE[precision] * 1.0001)


@FUZZ
@given(mtdata2_values())
def test_mtdata2_round_trip_in_every_precision_and_coordinate_system(case):
    values, precision, system = case
    decoded = xbus.decode_mtdata2(xbus.encode_mtdata2(values, precision, system))
    assert list(decoded.values) == list(values)
    for name, value in values.items():
        assert close(value, decoded.values[name], precision), name
    assert decoded.skipped == () and not decoded.truncated
    expected_systems = {n: system for n in values if n in xbus.WORLD_FRAME_OUTPUTS}
    assert decoded.coordinate_systems == expected_systems


def test_fixed_point_encodings_on_the_wire():
    fp1220 = xbus.encode_packet("temperature", -1.5, xbus.FP1220)
    assert fp1220 == struct.pack(">HBi", 0x0811, 4, -3 * 2**19)
    fp1632 = xbus.encode_packet("temperature", -1.25, xbus.FP1632)
    # a 32-bit fraction then a 16-bit signed integer part: -1.25 = -2 + 0.75
    assert fp1632 == struct.pack(">HBIh", 0x0812, 6, 3 * 2**30, -2)
    assert xbus.decode_mtdata2(fp1632).values["temperature"] == -1.25


def test_rotation_matrix_is_column_major_on_the_wire_and_rows_decoded():
    rows = ((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (7.0, 8.0, 9.0))
    packet = xbus.encode_packet("rotation_matrix", rows)
    assert struct.unpack(">9f", packet[3:]) == (1, 4, 7, 2, 5, 8, 3, 6, 9)
    assert xbus.decode_mtdata2(packet).values["rotation_matrix"] == rows


@FUZZ
@given(
    unknown=st.lists(
        st.tuples(
            st.sampled_from([0x0001, 0x5010, 0x7777, 0xA010, 0xD010]), st.binary(max_size=40)
        ),
        max_size=4,
    ),
    bad_size=st.booleans(),
)
def test_unknown_identifiers_are_skipped_by_their_size(unknown, bad_size):
    payload = sample_payload(7)
    extra = b"".join(struct.pack(">HB", xdi, len(d)) + d for xdi, d in unknown)
    if bad_size:  # a known identifier with a size that does not fit it
        extra += struct.pack(">HB", 0x2010, 3) + b"abc"
    parser = XbusParser()
    (msg,) = parser.feed(xbus.build(MID.MTDATA2, extra + payload))
    assert msg.mtdata2.values["packet_counter"] == 7
    assert msg.mtdata2.values["quaternion"] == (1.0, 0.0, 0.0, 0.0)
    assert parser.unknown_ids == len(unknown) + bad_size


def test_a_truncated_packet_keeps_what_came_before_it():
    payload = sample_payload(9) + struct.pack(">HB", 0x2030, 12) + b"\x00" * 5
    decoded = xbus.decode_mtdata2(payload)
    assert decoded.truncated and decoded.values["packet_counter"] == 9
    assert "euler" not in decoded.values


@FUZZ
@given(st.binary(max_size=300))
def test_decoding_random_payloads_never_raises(payload):
    xbus.decode_mtdata2(payload)


@pytest.mark.parametrize(
    "first, second",
    [
        (
            ("quaternion", (1.0, 0.0, 0.0, 0.0), xbus.FP1632),
            ("quaternion", (0.0, 1.0, 0.0, 0.0), xbus.FP1632),
        ),
        (("temperature", 20.0, xbus.FP1632), ("temperature", 21.0, xbus.FLOAT32)),
        (
            ("acceleration", (1.0, 0.0, 0.0), xbus.FP1220),
            ("acceleration", (2.0, 0.0, 0.0), xbus.FP1220),
        ),
        (("euler", (1.0, 2.0, 3.0), xbus.FLOAT32), ("euler", (4.0, 5.0, 6.0), xbus.FP1220)),
    ],
)
def test_a_repeated_output_is_decoded_once_never_converted_twice(first, second):
    payload = (
        xbus.encode_packet("packet_counter", 3)
        + xbus.encode_packet(*first)
        + xbus.encode_packet(*second)
    )
    for _ in range(2):  # the first decode compiles the layout, the second uses the cache
        parser = XbusParser()
        (msg,) = parser.feed(xbus.build(MID.MTDATA2, payload) + xbus.build(MID.GOTO_CONFIG_ACK))[:1]
        assert msg.mtdata2.values["packet_counter"] == 3
        assert msg.mtdata2.values[first[0]] == pytest.approx(first[1], abs=1e-5)
        assert parser.unknown_ids == 1 and parser.buffered == 0


def test_a_payload_the_decoder_cannot_explain_is_counted_and_the_stream_goes_on(monkeypatch):
    def broken(payload):
        raise IndexError("tuple index out of range")

    monkeypatch.setattr(xbus.frames, "decode_mtdata2", broken)  # the parser decodes there
    parser = XbusParser()
    frame = xbus.build(MID.MTDATA2, sample_payload(1))
    msgs = parser.feed(frame + xbus.build(MID.GOTO_CONFIG_ACK))
    assert [m.mid for m in msgs] == [MID.MTDATA2, MID.GOTO_CONFIG_ACK]
    assert msgs[0].mtdata2 is None and parser.malformed == 1 and parser.buffered == 0
    assert parser.feed(b"") == []  # nothing left in the buffer to raise again


def test_the_layout_cache_tells_apart_payloads_of_equal_length():
    a = xbus.encode_mtdata2({"packet_counter": 1, "status_word": 5})
    b = xbus.encode_mtdata2({"status_word": 6, "packet_counter": 2})
    assert len(a) == len(b)
    for _ in range(2):
        assert xbus.decode_mtdata2(a).values == {"packet_counter": 1, "status_word": 5}
        assert xbus.decode_mtdata2(b).values == {"status_word": 6, "packet_counter": 2}


# ----------------------------------------------------------------------------- configuration


def test_output_configuration_round_trip_and_defaults():
    settings_ = xbus.output_settings(xbus.DEFAULT_OUTPUTS, 100)
    data = xbus.encode_output_configuration(settings_)
    assert xbus.decode_output_configuration(data) == settings_
    by_name = {s.name: s for s in settings_}
    assert by_name["quaternion"].xdi == 0x2010 and by_name["quaternion"].rate_hz == 100
    assert by_name["packet_counter"].rate_hz == xbus.EVERY_PACKET
    with pytest.raises(ValueError):
        xbus.output_settings(["no_such_output"], 100)
    assert xbus.output_settings(["quaternion"], 50, xbus.FP1632, "NED")[0].xdi == 0x2016


def test_bench_parse_rate_measures_something():
    from capture.bench.components import bench_parse_rate

    assert bench_parse_rate(0.05) > 1000


def test_every_device_error_code_is_named():
    for code in (0x03, 0x04, 0x1E, 0x20, 0x21, 0x28, 0x29, 0x2A, 0x2B, 0x30, 0x33, 0x35):
        assert "does not know" not in xbus.error_text(code)
    assert "data overflow" in xbus.error_text(0x29)
    assert "buffer overflow" in xbus.error_text(0x2A)
    assert "output configuration" in xbus.error_text(0x35)
    # 0x28 carries the kind of device error in four more bytes
    assert "DSP crashed" in xbus.error_text(0x28, bytes([0x28, 0, 0, 0, 6]))
    assert "does not know" in xbus.error_text(0x99)


def test_baud_codes_include_3_5_mbaud_and_send_0x80_for_921600():
    """Xsens' library sends 0x80 for 921600 (xsbaud.c, XsBaud_rateToCode); 0x0A works
    only from MTi firmware 2.4.6 (xsbaudcode.h). Both decode to 921600."""
    assert xbus.BAUD_CODES[0x0E] == 3_500_000
    assert xbus.BAUD_CODE[921600] == 0x80 and xbus.BAUD_CODE[115200] == 0x02
    assert xbus.BAUD_CODES[0x0A] == xbus.BAUD_CODES[0x80] == 921600


def test_only_the_timestamp_group_is_asked_for_in_every_packet():
    settings = xbus.output_settings(xbus.DEFAULT_OUTPUTS, 100)
    at_ffff = {s.name for s in settings if s.rate_hz == xbus.EVERY_PACKET}
    assert at_ffff == {"packet_counter", "sample_time_fine"}
    assert {s.name: s.rate_hz for s in settings}["status_word"] == 100


def test_the_link_budget_of_the_default_outputs():
    """73 bytes a message (68 of data, 5 of frame); 10 bits a byte on the line."""
    settings = xbus.output_settings(xbus.DEFAULT_OUTPUTS, 100)
    budget = xbus.link_budget(settings, 115200)
    assert budget.bytes_per_message == 73 and budget.bits_per_s == 73_000
    assert budget.fits
    assert not xbus.link_budget(xbus.output_settings(xbus.DEFAULT_OUTPUTS, 200), 115200).fits
    assert xbus.baud_that_fits(xbus.output_settings(xbus.DEFAULT_OUTPUTS, 400)) == 460800
    assert xbus.baud_that_fits(xbus.output_settings(xbus.DEFAULT_OUTPUTS, 2000)) == 2_000_000
