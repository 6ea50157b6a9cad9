"""Damaged recordings: a flipped bit costs its chunk only; every reader says so in one line,
`walkcap info` reports it and `walkcap recover` copies every intact message."""

from __future__ import annotations

import shutil

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.journal import journal_path
from capture.recording.reader import open_recording
from capture.recording.recover import recover
from tests.recording_fixtures import write_recording
from tui import cli


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("damage") / "trial.mcap"
    write_recording(path, seconds=3.0, chunk_interval_s=0.5)
    return path


def chunks(path):
    """(offset, length, message count, start ns, end ns) of every chunk, in file order."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        out = []
        for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(c.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            n = sum(isinstance(r, Message) for r in breakup_chunk(chunk))
            out.append((c.chunk_start_offset, c.chunk_length, n, c.message_start_time))
    return out


def total_messages(path) -> int:
    return sum(t.count for t in open_recording(path).topics.values())


def flipped(recording, tmp_path, at: int, name: str = "flipped.mcap"):
    data = bytearray(recording.read_bytes())
    data[at] ^= 0x10
    out = tmp_path / name
    out.write_bytes(bytes(data))
    return out


def one_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("k", [0, 2, -1])
def test_one_flipped_bit_in_a_chunk_costs_that_chunk_only(recording, tmp_path, k):
    table = chunks(recording)
    assert len(table) >= 5
    offset, length, lost, _ = table[k]
    bad = flipped(recording, tmp_path, offset + length // 2)
    report = recover(bad, tmp_path / "out.mcap")
    assert report.messages == total_messages(recording) - lost  # every intact chunk kept
    (damage,) = report.damaged
    assert damage.offset == offset and damage.length >= length
    assert T.DEPTH in damage.topics and "damaged chunk" in damage.reason
    rec = open_recording(report.output)
    assert rec.complete and sum(t.count for t in rec.topics.values()) == report.messages
    assert f"at byte {offset}" in rec.metadata["recovery"]["damaged"]


def test_damage_in_the_first_kilobytes_loses_no_message(recording, tmp_path):
    bad = flipped(recording, tmp_path, 9)  # the header record's length
    report = recover(bad, tmp_path / "out.mcap")
    assert report.messages == total_messages(recording)
    assert report.damaged and report.damaged[0].offset < 4096


def test_an_unfinished_file_damaged_in_the_middle_keeps_the_chunks_after_it(recording, tmp_path):
    table = chunks(recording)
    bad = bytearray(recording.read_bytes())
    bad[table[1][0] + table[1][1] // 2] ^= 0x01
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(bad[: table[4][0] + 100]))  # a kill -9 inside chunk 4
    report = recover(cut, tmp_path / "out.mcap")
    kept = sum(n for _, _, n, _ in table[:4]) - table[1][2]
    assert report.messages == kept and len(report.damaged) == 1


def test_a_chunk_whose_crc_fails_after_decompression_is_damaged(recording, tmp_path):
    """A chunk stored without compression: only its CRC can tell the bytes changed."""
    from capture.recording.messages import chunk_messages

    offset, length, _, _ = chunks(recording)[1]
    with open(recording, "rb") as f:
        f.seek(offset + 9)
        chunk = Chunk.read(ReadDataStream(f))
    import zstandard
    from mcap.data_stream import RecordBuilder

    raw = bytearray(zstandard.ZstdDecompressor().decompress(chunk.data, chunk.uncompressed_size))
    raw[len(raw) // 2] ^= 0x01
    builder = RecordBuilder()
    Chunk(
        compression="",
        data=bytes(raw),
        message_end_time=chunk.message_end_time,
        message_start_time=chunk.message_start_time,
        uncompressed_crc=chunk.uncompressed_crc,
        uncompressed_size=chunk.uncompressed_size,
    ).write(builder)
    path = tmp_path / "plain.mcap"
    path.write_bytes(builder.end())
    with open(path, "rb") as f, pytest.raises(ValueError, match="CRC"):
        list(chunk_messages(f, 0, path.stat().st_size, {1, 2, 3, 4, 5}))


def test_info_reports_damaged_chunks(recording, tmp_path, capsys):
    offset, length, _, _ = chunks(recording)[2]
    bad = flipped(recording, tmp_path, offset + 100)
    assert cli.main(["info", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "state       complete" not in out
    assert "damaged: 1 region" in out and f"damaged chunk at byte {offset}" in out
    from capture.recording.checking import check

    assert check(recording).damaged == []


@pytest.mark.parametrize(
    "command",
    [
        ["replay", "--fast"],
        ["eval", "recordings", "--reference", "terrain"],
        ["train", "--epochs", "1", "--data"],
        ["export", "--format", "csv"],
        ["share", "--shift-days", "-1"],
    ],
)
def test_every_reader_stops_at_damage_with_one_line_naming_it(recording, tmp_path, capsys, command):
    offset, _, _, _ = chunks(recording)[2]
    bad = flipped(recording, tmp_path, offset + 100)
    extra = {
        "train": ["--out", str(tmp_path / "m.pt")],
        "export": ["-o", str(tmp_path / "t")],
        "share": ["-o", str(tmp_path / "s")],
    }
    extra = extra.get(command[0], [])
    assert cli.main([*command, str(bad), *extra]) == 1
    line = one_line(capsys.readouterr().err)
    assert f"at byte {offset}" in line and "walkcap recover" in line
    assert " s " in line or " s:" in line  # the time span


def test_the_unfinished_reader_stops_at_damage_too(recording, tmp_path):
    table = chunks(recording)
    bad = bytearray(recording.read_bytes())
    bad[table[1][0] + 300] ^= 0x01
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bytes(bad[: table[4][0] + 100]))
    rec = open_recording(cut)
    assert not rec.complete and len(rec.damaged) == 1
    with pytest.raises(CaptureError, match=f"at byte {table[1][0]}"):
        list(rec.messages([T.DEPTH]))


@pytest.mark.parametrize("command", [["info"], ["recover"], ["replay", "--fast"]])
def test_garbage_after_the_magic_is_an_error(recording, tmp_path, capsys, command):
    bad = tmp_path / "garbage.mcap"
    bad.write_bytes(recording.read_bytes()[:8] + b"not a record, just garbage " * 200)
    assert cli.main([*command, str(bad)]) == 1
    assert "garbage.mcap" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "garbage.recovered.mcap").exists()


def test_a_named_journal_that_does_not_exist_is_an_error(recording, tmp_path, capsys):
    copy = tmp_path / "trial.mcap"
    shutil.copy(recording, copy)
    missing = tmp_path / "missing.jsonl"
    assert cli.main(["recover", str(copy), "--journal", str(missing)]) == 1
    assert "missing.jsonl" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "trial.recovered.mcap").exists()
    shutil.copy(journal_path(recording), tmp_path / "there.jsonl")
    assert cli.main(["recover", str(copy), "--journal", str(tmp_path / "there.jsonl")]) == 0
