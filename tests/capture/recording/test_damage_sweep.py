"""Single-bit damage where no CRC covers the byte (record types, lengths, the summary, the
journal): nothing is lost without being reported, no message or label appears that the
original never had, and no byte makes an internal error. A sample of each class of the
full sweep (`python -m tests.capture.recording.damage_sweep FILE`), and one test per case the
issue names."""

from __future__ import annotations

import json
import shutil
import struct
import zlib

import pytest
from mcap.reader import make_reader

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.checking import check
from capture.recording.journal import check_journal, encode_line, journal_path
from capture.recording.reader import open_recording
from capture.recording.recover import recover
from capture.recording.writer import Recorder
from tests.capture.recording.damage_sweep import records, sweep
from tests.recording_fixtures import write_recording
from tui import cli


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "trial.mcap"
    write_recording(path, seconds=1.0, chunk_interval_s=0.25)
    return path


def total(path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages(log_time_order=False))


def flipped(recording, tmp_path, at: int, bit: int, cut: int | None = None):
    data = bytearray(recording.read_bytes())
    data[at] ^= 1 << bit
    out = tmp_path / "flipped.mcap"
    out.write_bytes(bytes(data[:cut]))
    return out


def record_offsets(path, opcode: int) -> list[int]:
    return [at for at, op, _ in records(path.read_bytes()) if op == opcode]


@pytest.mark.parametrize("kind", ["opcode", "length", "summary", "journal", "cut", "records"])
def test_a_sample_of_each_class_loses_nothing_silently(recording, kind):
    totals, failing = sweep(recording, {kind}, sample=12)
    cases, silent, phantom, internal, _ = totals[kind]
    assert cases == 12
    assert (silent, phantom, internal) == (0, 0, 0), failing[:3]


def test_a_chunk_whose_type_byte_flips_is_kept_and_reported(recording, tmp_path, capsys):
    """0x06 -> 0x07: the chunk read as a message index was dropped, "complete file"."""
    first = record_offsets(recording, 0x06)[0]
    bad = flipped(recording, tmp_path, first, 0)
    assert cli.main(["recover", str(bad), "-o", str(tmp_path / "out.mcap")]) == 0
    out = capsys.readouterr().out
    assert "complete file" not in out and f"at byte {first}" in out
    assert total(tmp_path / "out.mcap") == total(recording)
    assert [d.offset for d in check(bad).damaged] == [first]


def test_a_message_index_read_as_data_end_does_not_end_the_file(recording, tmp_path):
    """0x07 -> 0x0f: recovery stopped at the first chunk's index."""
    index = record_offsets(recording, 0x07)[0]
    report = recover(flipped(recording, tmp_path, index, 3), tmp_path / "out.mcap")
    assert total(tmp_path / "out.mcap") == total(recording)
    assert not report.complete and [d.offset for d in report.damaged] == [index]


def test_a_message_index_read_as_a_message_injects_nothing(recording, tmp_path):
    """0x07 -> 0x05: a garbage message on a real channel (an internal error on /labels)."""
    for index in record_offsets(recording, 0x07)[:12]:
        report = recover(
            flipped(recording, tmp_path, index, 1), tmp_path / "out.mcap", overwrite=True
        )
        assert report.messages == total(recording) and report.damaged


def test_a_chunk_read_as_a_footer_does_not_stop_the_reader_of_a_cut_file(recording, tmp_path):
    """0x06 -> 0x02 in a file cut by a crash: every reader stopped at the first chunk."""
    chunks = record_offsets(recording, 0x06)
    bad = flipped(recording, tmp_path, chunks[0], 2, cut=chunks[-1] + 100)
    rec = open_recording(bad)
    assert not rec.complete
    assert len(rec.read(T.DEPTH)) == sum(1 for _ in range(rec.topics[T.DEPTH].count)) > 0
    whole = open_recording(recording).topics[T.DEPTH].count
    assert rec.topics[T.DEPTH].count < whole  # the cut chunk only


def test_a_flipped_length_keeps_the_neighbours_and_names_the_record(recording, tmp_path):
    chunks = record_offsets(recording, 0x06)
    at = chunks[1]
    body = at + 9
    (name_length,) = struct.unpack_from("<I", recording.read_bytes(), body + 28)
    # the records length inside the chunk: nothing but the head's length can fix it
    bad = flipped(recording, tmp_path, body + 32 + name_length + 2, 5)
    report = recover(bad, tmp_path / "out.mcap")
    assert report.damaged and report.damaged[0].offset == at
    assert report.messages == total(recording)  # the head's length gives the extent back
    bad = flipped(recording, tmp_path, at + 3, 1)  # the head's own length
    report = recover(bad, tmp_path / "out.mcap", overwrite=True)
    assert report.damaged[0].offset == at and report.messages == total(recording)


def test_a_damaged_summary_is_not_believed(recording, tmp_path, capsys):
    """A flip in the statistics emptied /camera/depth for info, replay wrote nothing."""
    data = recording.read_bytes()
    (stats,) = record_offsets(recording, 0x0B)
    whole = open_recording(recording).topics[T.DEPTH].count
    depth = next(
        cid
        for cid, c in make_reader(open(recording, "rb")).get_summary().channels.items()
        if c.topic == T.DEPTH
    )
    # message count u64, schema u16, channel u32, attachment u32, metadata u32, chunk u32,
    # start u64, end u64, then the map's byte length u32 and (channel u16, count u64) pairs
    body = stats + 9
    at = body + 8 + 2 + 4 + 4 + 4 + 4 + 8 + 8 + 4
    while struct.unpack_from("<H", data, at)[0] != depth:
        at += 10
    bad = flipped(recording, tmp_path, at, 0)  # the depth channel's id in the counts
    rec = open_recording(bad)
    assert not rec.complete and rec.topics[T.DEPTH].count == whole
    assert len(rec.read(T.DEPTH)) == whole
    assert cli.main(["info", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "summary CRC mismatch" in out and "state       complete" not in out


def test_one_bit_of_the_session_record_is_reported_by_name(tmp_path, capsys):
    """Subject S77 read back as S76: MCAP checks no metadata byte; the digest does."""
    path = tmp_path / "trial.mcap"
    rec = Recorder(path, metadata={"session": {"subject": "S77", "condition": "indoor"}})
    rec.start()
    rec.write_label(5_000_000_000, "LG", "operator")
    rec.close()
    data = bytearray(path.read_bytes())
    at = data.index(b'"S77"') + 3
    data[at] ^= 0x01  # "7" -> "6"
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert open_recording(bad).metadata["session"]["subject"] == "S76"  # what MCAP reads
    assert [d.record for d in open_recording(bad).damaged] == ["metadata session"]
    assert [d.record for d in check(bad).damaged] == ["metadata session"]
    assert cli.main(["info", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "state       complete" not in out and "metadata session (" in out
    assert "fails its digest" in out
    report = recover(bad, tmp_path / "out.mcap")
    assert not report.complete and [d.record for d in report.damaged] == ["metadata session"]
    assert cli.main(["recover", str(bad), "-o", str(tmp_path / "out2.mcap")]) == 0
    out = capsys.readouterr().out
    assert "complete file" not in out and "found damaged metadata session" in out
    assert open_recording(path).damaged == [] and check(path).complete  # the original


def test_a_length_inside_a_record_that_the_parser_reads_past_is_caught(recording, tmp_path):
    """A value's length prefix flipped (6 -> 22): the mcap parser still reads a record, and
    writing it again gives the original bytes: the digest is over the file's own bytes."""
    data = bytearray(recording.read_bytes())
    header_library_length = 8 + 9 + 4  # magic, head, the empty profile's length
    data[header_library_length] ^= 0x80
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert [d.record for d in check(bad).damaged] == ["header"]
    assert not recover(bad, tmp_path / "out.mcap").complete
    with pytest.raises(CaptureError, match="damaged"):  # the index's reader: one line
        open_recording(bad)


def test_the_summary_path_checks_schemas_and_channels_too(recording, tmp_path):
    """A reader that believes the summary (its CRC recomputed over a flipped channel
    record: as if the file had none) still finds the channel by its digest."""
    data = bytearray(recording.read_bytes())
    channel = next(at for at, op, _ in records(bytes(data)) if op == 0x04 and at > data_end(data))
    data[channel + 9 + 8 + 1] ^= 0x04  # the topic name: id u16, schema u16, length u32
    footer = len(data) - 8 - 29
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    crc = zlib.crc32(bytes(data[summary_start : footer + 9 + 16]))
    struct.pack_into("<I", data, footer + 9 + 16, crc)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    (cid,) = struct.unpack_from("<H", data, channel + 9)
    assert [d.record for d in open_recording(bad).damaged] == [f"channel {cid}"]


def test_record_digests_name_what_fails():
    from mcap.records import Metadata

    from capture.recording.digests import check_records, record_bytes, seal

    session = record_bytes(Metadata("session", {"subject": '"S77"'}))
    end = record_bytes(Metadata("recording_end", {"messages": "5"}))
    stored = [seal([("metadata session", session)]), seal([("metadata recording_end", end)])]
    assert (
        check_records([("metadata session", session)], stored[:1], required=True, finished=True)
        == []
    )
    bad = session.replace(b"S77", b"S76")
    [p] = check_records([("metadata session", bad)], stored[:1], required=True, finished=True)
    assert p.key == "metadata session" and "fails its digest" in p.why
    broken = {**stored[1], "metadata recording_end": "00000000"}  # the digest record itself
    problems = check_records(
        [("metadata session", session), ("metadata recording_end", end)],
        [stored[0], broken],
        required=True,
        finished=True,
    )
    assert [p.key for p in problems] == ["record_digests #2", "metadata recording_end"]
    missing = check_records([], stored[:1], required=True, finished=True)
    assert [p.key for p in missing] == ["metadata session"] and "missing" in missing[0].why
    assert check_records([], stored[:1], required=True, finished=False) == []  # cut off


def data_end(data) -> int:
    return next(at for at, op, _ in records(bytes(data)) if op == 0x0F)


def journal_lines(path):
    return journal_path(path).read_bytes().splitlines(keepends=True)


def test_each_journal_line_carries_its_crc(recording, tmp_path, capsys):
    copy = tmp_path / "trial.mcap"
    shutil.copy(recording, copy)
    lines = journal_lines(recording)
    assert all(json.loads(line)["crc32"] for line in lines)
    number = next(k for k, line in enumerate(lines, 1) if b'"label"' in line)
    damaged = bytearray(lines[number - 1])
    damaged[damaged.index(b"time_ns") + 1] ^= 0x01  # the key: a label at time 0 before
    lines[number - 1] = bytes(damaged)
    journal_path(copy).write_bytes(b"".join(lines))
    assert check_journal(journal_path(copy)).skipped == [f"line {number}: CRC mismatch"]
    assert cli.main(["recover", str(copy)]) == 0
    assert f"skipped journal line {number}: CRC mismatch" in capsys.readouterr().out


@pytest.mark.parametrize(
    "entry",
    [
        {"type": "label", "time_ns": "abc", "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": None, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": 1e30, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": 2**64, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": -5, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": float("nan"), "mode": "LG", "source": "operator"},
        {"type": "event", "time_ns": 5, "device": "operator", "kind": "m", "details": "x"},
    ],
    ids=["text", "null", "1e30", "2^64", "negative", "nan", "details"],
)
def test_impossible_journal_values_are_skipped_and_reported(recording, tmp_path, entry):
    copy = tmp_path / "trial.mcap"
    shutil.copy(recording, copy)
    lines = journal_lines(recording)
    lines.insert(2, encode_line(entry))
    journal_path(copy).write_bytes(b"".join(lines))
    report = recover(copy, tmp_path / "out.mcap")
    assert [s.split(":")[0] for s in report.journal_skipped] == ["line 3"]


def test_a_stock_jsonl_reader_reads_the_journal(recording):
    """json.loads per line and pandas' read_json(lines=True) take the file as it is."""
    import pandas as pd

    path = journal_path(recording)
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert [r["type"] for r in rows][:1] == ["start"] and "label" in {r["type"] for r in rows}
    frame = pd.read_json(path, lines=True)
    assert list(frame["type"]) == [r["type"] for r in rows]
    believed = check_journal(path)
    assert believed.skipped == [] and len(believed.entries) == len(rows)
    assert all("crc32" not in e for e in believed.entries)  # the check is no entry's value


def test_a_journal_of_tab_and_crc_lines_still_reads(recording, tmp_path):
    entries = [
        {"type": "label", "time_ns": 5, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": 9, "mode": "US", "source": "operator"},
    ]
    texts = [json.dumps(e, separators=(",", ":")).encode() for e in entries]
    lines = [t + b"\t%08x\n" % zlib.crc32(t) for t in texts]
    lines[1] = lines[1].replace(b"US", b"UT")
    old = tmp_path / "tabbed.jsonl"
    old.write_bytes(b"".join(lines))
    read = check_journal(old)
    assert read.entries == entries[:1] and read.skipped == ["line 2: CRC mismatch"]


def test_a_line_without_its_check_in_a_checked_journal_is_damage(tmp_path):
    path = tmp_path / "j.jsonl"
    good = {"type": "label", "time_ns": 5, "mode": "LG", "source": "operator"}
    bare = json.dumps({**good, "time_ns": 7}).encode() + b"\n"
    path.write_bytes(encode_line(good) + bare)
    assert check_journal(path).skipped == ["line 2: no CRC (damaged)"]


def test_a_journal_without_crcs_still_reads_and_a_cut_line_is_reported(recording, tmp_path):
    old = tmp_path / "old.jsonl"
    entries = [
        {"type": "label", "time_ns": 5, "mode": "LG", "source": "operator"},
        {"type": "label", "time_ns": 9, "mode": "US", "source": "operator"},
    ]
    text = "".join(json.dumps(e) + "\n" for e in entries)
    old.write_text(text + '{"type": "label", "ti')
    read = check_journal(old)
    assert read.entries == entries
    assert read.skipped == ["line 3: cut off (a crash while it was written)"]
