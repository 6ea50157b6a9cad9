"""Fuzzing of the Xbus parser: random byte streams, each followed by valid messages.

Each stream is one of: an MTData2 frame with a valid checksum and a random layout (repeated,
unknown or wrongly sized outputs, any precision), a valid frame with bits flipped or cut
short, or random bytes rich in preambles. After it come valid messages numbered by their
packet counter, enough to fill the largest frame a false header can announce, fed in random
chunk sizes as a serial line delivers them. A stream fails when the parser raises; the first
valid message is lost when a false frame that passes the 8-bit checksum swallows its start.
"""

from __future__ import annotations

import random
import struct
import time
from dataclasses import dataclass, field

from devices import xbus

# A sample of the default outputs, as a measuring MTi sends it (packet_counter set per message).
SAMPLE_VALUES = {
    "packet_counter": 0,
    "sample_time_fine": 123456,
    "quaternion": (1.0, 0.0, 0.0, 0.0),
    "acceleration": (0.0, 0.0, 9.81),
    "rate_of_turn": (0.01, 0.02, 0.03),
    "status_word": 3,
}
_KNOWN_XDIS = tuple(xbus.OUTPUTS)


def _sentinel_tail(max_data: int) -> list[bytes]:
    """Valid messages numbered 0, 1, ... covering at least one largest frame."""
    frames = []
    total = 0
    k = 0
    while total < max_data + 8 + 200:
        payload = xbus.encode_mtdata2({**SAMPLE_VALUES, "packet_counter": k})
        frame = xbus.build(xbus.MID.MTDATA2, payload)
        frames.append(frame)
        total += len(frame)
        k += 1
    return frames


def _random_packet(rng: random.Random) -> bytes:
    r = rng.random()
    if r < 0.08:  # an unknown identifier
        xdi = rng.randrange(0x10000)
        size = rng.randrange(0, 40)
    else:
        base = rng.choice(_KNOWN_XDIS)
        xdi = base | (rng.randrange(4) if xbus.OUTPUTS[base][1] == "real" else 0)
        xdi |= rng.choice((0x0, 0x4, 0x8, 0xC)) if rng.random() < 0.3 else 0
        size = xbus.value_size(xdi) or 0
        if r > 0.92:  # the right identifier with the wrong size
            size = max(0, size + rng.choice((-4, -2, -1, 1, 2, 4)))
    return struct.pack(">HB", xdi, size) + rng.randbytes(size)


def _random_layout_payload(rng: random.Random) -> bytes:
    packets = [_random_packet(rng) for _ in range(rng.randrange(1, 7))]
    if rng.random() < 0.5:  # repeat an output, as a misconfigured device can
        packets.insert(rng.randrange(len(packets) + 1), rng.choice(packets))
    payload = b"".join(packets)
    if rng.random() < 0.1:  # a packet running past the end
        payload = payload[: rng.randrange(len(payload) + 1)]
    return payload[: xbus.MAX_DATA]


def _random_stream(rng: random.Random) -> tuple[str, bytes]:
    r = rng.random()
    if r < 0.5:
        return "layout", xbus.build(xbus.MID.MTDATA2, _random_layout_payload(rng))
    if r < 0.8:
        frame = bytearray(xbus.build(xbus.MID.MTDATA2, _random_layout_payload(rng)))
        for _ in range(rng.randrange(1, 4)):
            frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
        if rng.random() < 0.3:
            frame = frame[: rng.randrange(1, len(frame) + 1)]
        return "damaged", bytes(frame)
    n = rng.randrange(1, 64)
    data = bytearray(rng.randbytes(n))
    for _ in range(rng.randrange(1, 4)):  # preambles and the master bus id make false headers
        k = rng.randrange(n)
        data[k : k + 2] = b"\xfa\xff"
    return "garbage", bytes(data[:n])


@dataclass
class FuzzReport:
    streams: int
    seed: int
    seconds: float
    exceptions: int = 0
    lost_next: int = 0  # streams whose first valid message after them was lost
    false_frames: int = 0  # frames accepted from damaged or random bytes
    malformed: int = 0  # MTData2 payloads the parser counted as malformed
    by_kind: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)  # the first failures, to reproduce

    def to_dict(self) -> dict:
        return {
            "streams": self.streams,
            "seed": self.seed,
            "seconds": round(self.seconds, 1),
            "exceptions": self.exceptions,
            "lost_next": self.lost_next,
            "lost_next_rate": self.lost_next / self.streams if self.streams else 0.0,
            "false_frames": self.false_frames,
            "malformed": self.malformed,
            "by_kind": self.by_kind,
            "examples": self.examples,
        }


def fuzz_parser(streams: int, seed: int = 0, progress=None) -> FuzzReport:
    """Feed `streams` random streams, each to a new parser; count exceptions and losses."""
    rng = random.Random(seed)
    tail_frames = _sentinel_tail(xbus.MAX_DATA)
    tail = b"".join(tail_frames)
    payload_size = len(tail_frames[0]) - 5
    report = FuzzReport(streams=streams, seed=seed, seconds=0.0)
    start = time.monotonic()
    for k in range(streams):
        kind, head = _random_stream(rng)
        report.by_kind[kind] = report.by_kind.get(kind, 0) + 1
        data = head + tail
        parser = xbus.XbusParser()
        messages = []
        try:
            i = 0
            while i < len(data):  # serial reads: a few bytes to a few hundred
                step = rng.choice((1, 7, 64, 256, 4096))
                messages += parser.feed(data[i : i + step])
                i += step
        except Exception as e:  # noqa: BLE001 - counting every failure is the point
            report.exceptions += 1
            if len(report.examples) < 5:
                report.examples.append(f"{kind} {type(e).__name__}: {e} stream={head.hex()}")
            continue
        report.malformed += parser.malformed
        counters = set()
        for msg in messages:
            m = msg.mtdata2
            if (
                m is not None
                and len(msg.data) == payload_size
                and m.values.get("sample_time_fine") == 123456
            ):
                counters.add(m.values.get("packet_counter"))
        if 0 not in counters:
            report.lost_next += 1
        if kind != "layout":
            report.false_frames += max(0, len(messages) - len(tail_frames))
        if progress and (k + 1) % 100_000 == 0:
            progress(f"{k + 1} streams, {report.exceptions} exceptions")
    report.seconds = time.monotonic() - start
    return report
