"""The damage sweep: single-bit damage where no CRC covers a byte, and what every reader
makes of it. Each case flips one bit of a copy of a recording (or of its journal), then
runs `recover` and the reader (`open_recording` + every message) on it, finished and cut
off by a crash, and counts against the undamaged file:

- silent losses: messages (or journal labels) missing with no damage reported,
- phantom messages: messages (or labels) the original never had,
- internal errors: anything but walkcap's one-line errors (CaptureError).

Class "records" flips bits inside the records MCAP itself leaves unchecked (the header,
metadata records, and the summary's schemas and channels; capture.recording.digests
protects them): every bit of the header and of each metadata record but the digests' own,
one bit a byte of those; each flip must be reported by `check` (behind `walkcap info`),
by `recover` and by `open_recording` (its `damaged`, or one line), else it counts as a
silent loss.

All three must be 0. The suite runs a sample of each class
(tests/capture/recording/test_damage_sweep.py); the full sweep is

    python -m tests.capture.recording.damage_sweep FILE [--jobs 2] \
        [--classes opcode,length,summary,journal,cut,records]

(FILE: a finished recording with its journal beside it; with `--make` a small
synthetic one is written there first). Class "cut" cuts the file at every record
boundary instead (+-1, and with a zero-filled tail): every chunk before the cut must
survive. It prints one line per class and a total, and exits 1 when any
count is not 0.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import shutil
import struct
import sys
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

RECORD_HEAD = struct.Struct("<BQ")
MAGIC_SIZE = 8


@dataclass
class Case:
    kind: str  # opcode | length | summary | journal
    offset: int  # byte flipped (in the journal for kind "journal")
    bit: int
    cut: int | None = None  # the file cut here (a crash) before the flip, None: finished
    what: str = ""


@dataclass
class Outcome:
    silent_loss: int = 0
    phantom: int = 0
    internal: int = 0
    lost_reported: int = 0  # messages lost with damage reported (allowed)
    notes: list[str] = field(default_factory=list)


def records(data: bytes):
    """(offset, opcode, length) of every record, data section then summary."""
    out, at = [], MAGIC_SIZE
    while at + RECORD_HEAD.size <= len(data) - MAGIC_SIZE:
        opcode, length = RECORD_HEAD.unpack_from(data, at)
        out.append((at, opcode, length))
        at += RECORD_HEAD.size + length
    return out


def plan(
    path: Path, classes: set[str], sample: int | None = None, every_bit: bool = False
) -> list[Case]:
    """Every case of each class; `sample`: about that many per class, spread evenly. The
    summary gets one bit a byte (the byte's offset mod 8), or all eight with `every_bit`."""
    data = path.read_bytes()
    table = records(data)
    data_end = next(at for at, op, _ in table if op == 0x0F)
    chunks = [(at, length) for at, op, length in table if op == 0x06]
    # a crash cut: inside the last chunk but one (the data section stops there)
    cut = chunks[-2][0] + chunks[-2][1] // 2 if len(chunks) >= 3 else None
    cases: dict[str, list[Case]] = collections.defaultdict(list)
    for at, opcode, _ in table:
        name = f"{opcode:#04x} record at {at}"
        for cutoff in (None, cut):
            if cutoff is not None and at + RECORD_HEAD.size > cutoff:
                continue
            for bit in range(8):
                cases["opcode"].append(Case("opcode", at, bit, cutoff, name))
            for bit in range(64):
                cases["length"].append(Case("length", at + 1 + bit // 8, bit % 8, cutoff, name))
        if opcode == 0x06:  # a chunk's own length fields: uncompressed size, name, records
            body = at + RECORD_HEAD.size
            (name_length,) = struct.unpack_from("<I", data, body + 28)
            fields = [(body + 16, 64), (body + 28, 32), (body + 32 + name_length, 64)]
            for start, bits in fields:
                for bit in range(bits):
                    cases["length"].append(
                        Case("length", start + bit // 8, bit % 8, None, f"chunk field at {start}")
                    )
    for at, _, length in table:  # a crash at every record boundary, +-1, zero-filled tails
        if at > data_end:
            break
        for cutoff in (at - 1, at, at + 1):
            cases["cut"].append(Case("cut", cutoff, -1, cutoff, "cut"))
        middle = at + (RECORD_HEAD.size + length) // 2
        for cutoff in (at, middle):
            cases["cut"].append(Case("cut", cutoff, -2, cutoff, "cut, zero-filled tail"))
    for at, opcode, length in table:  # the bytes MCAP checks nowhere but by our digests
        if opcode not in (0x01, 0x03, 0x04, 0x0C) or (opcode in (0x03, 0x04) and at < data_end):
            continue
        body = at + RECORD_HEAD.size
        digest = data[body + 4 : body + 4 + len(b"record_digests")] == b"record_digests"
        name = f"{opcode:#04x} record at {at}"
        for byte in range(body, body + length):
            every = opcode in (0x01, 0x0C) and not digest
            for bit in range(8) if every or every_bit else (byte % 8,):
                cases["records"].append(Case("records", byte, bit, None, name))
    summary_start = data_end + RECORD_HEAD.size + 4
    for at in range(summary_start, len(data)):
        for bit in range(8) if every_bit else (at % 8,):
            cases["summary"].append(Case("summary", at, bit, None, "summary"))
    journal = Path(str(path) + ".journal.jsonl")
    if journal.exists():
        size = journal.stat().st_size
        for cutoff in (None, cut):
            for at in range(size):
                for bit in range(8):
                    cases["journal"].append(Case("journal", at, bit, cutoff, "journal"))
    out = []
    for kind in ("opcode", "length", "summary", "journal", "cut", "records"):
        if kind not in classes:
            continue
        items = cases[kind]
        if sample and len(items) > sample:
            step = len(items) / sample
            items = [items[int(k * step)] for k in range(sample)]
        out.extend(items)
    return out


def _message_key(topic: str, log_time: int, sequence: int, data: bytes) -> tuple:
    return (topic, log_time, sequence, zlib.crc32(data))


def file_messages(path: Path) -> collections.Counter:
    """Every message of a finished, undamaged file (the original, a recovered copy)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        return collections.Counter(
            _message_key(c.topic, m.log_time, m.sequence, m.data)
            for _, c, m in reader.iter_messages(log_time_order=False)
        )


def label_keys(path: Path) -> set:
    from capture.recording.reader import open_recording

    return {
        (int(m.data["time_ns"]), m.data.get("mode", ""), m.data.get("source", ""))
        for m in open_recording(path).messages(["/labels"])
    }


@dataclass
class Baseline:
    path: Path
    messages: collections.Counter  # of the finished file
    cut_messages: dict  # cut offset -> Counter of what a cut copy holds intact
    labels: set  # every label the file and its journal hold
    journal_labels: set
    chunks: list = field(default_factory=list)  # (end offset, Counter) of every chunk

    def before(self, cut: int) -> collections.Counter:
        """The messages of the chunks that end before a cut: what must survive it."""
        out: collections.Counter = collections.Counter()
        for end, messages in self.chunks:
            if end <= cut:
                out += messages
        return out


def baseline(path: Path, cuts: set) -> Baseline:
    from capture.recording.journal import journal_path, read_journal
    from capture.recording.recover import recover

    messages = file_messages(path)
    cut_messages = {}
    work = Path(tempfile.mkdtemp(prefix="sweep-base-"))
    for cut in cuts:
        if cut is None:
            continue
        cut_file = work / "cut.mcap"
        cut_file.write_bytes(path.read_bytes()[:cut])
        report = recover(cut_file, work / "out.mcap", journal=None, overwrite=True)
        assert not report.damaged, report.damaged
        got = file_messages(work / "out.mcap")
        cut_messages[cut] = got - collections.Counter(
            k for k in got if k[0] == "/labels" and k not in messages
        )
    journal = {
        (int(e["time_ns"]), e.get("mode", ""), e.get("source", ""))
        for e in read_journal(journal_path(path))
        if e.get("type") == "label"
    }
    labels = label_keys(path) | journal
    shutil.rmtree(work, ignore_errors=True)
    return Baseline(path, messages, cut_messages, labels, journal, chunk_messages(path))


def chunk_messages(path: Path) -> list:
    from mcap.reader import make_reader

    from capture.recording.messages import chunk_messages

    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        every = set(summary.channels)
        for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            got = collections.Counter(
                _message_key(summary.channels[cid].topic, log, seq, data)
                for cid, seq, log, _, data in chunk_messages(
                    f, c.chunk_start_offset, c.chunk_length, every
                )
            )
            out.append((c.chunk_start_offset + c.chunk_length, got))
    return out


def damaged_copy(base: Baseline, case: Case, work: Path) -> Path:
    from capture.recording.journal import journal_path

    data = bytearray(base.path.read_bytes())
    journal = bytearray(journal_path(base.path).read_bytes())
    if case.kind == "journal":
        journal[case.offset] ^= 1 << case.bit
    elif case.kind != "cut":
        data[case.offset] ^= 1 << case.bit
    if case.cut is not None:
        data = data[: case.cut]
    if case.bit == -2:  # the file system's zeros after a power loss
        data += bytes(64 * 1024)
    path = work / "damaged.mcap"
    path.write_bytes(bytes(data))
    journal_path(path).write_bytes(bytes(journal))
    return path


def run_case(base: Baseline, case: Case, work: Path) -> Outcome:
    from capture.errors import CaptureError
    from capture.recording.reader import open_recording
    from capture.recording.recover import recover

    out = Outcome()
    path = damaged_copy(base, case, work)
    if case.kind == "records":
        _records_reported(path, work, out)
    if case.kind == "cut":
        expected = base.before(case.cut)
    else:
        expected = base.messages if case.cut is None else base.cut_messages[case.cut]
    # recover
    try:
        report = recover(path, work / "out.mcap", overwrite=True)
    except CaptureError:
        report = None  # one line: reported
    except Exception as e:  # noqa: BLE001 - what the sweep counts
        out.internal += 1
        out.notes.append(f"recover: {type(e).__name__}: {e}")
        report = None
    if report is not None:
        got = file_messages(work / "out.mcap")
        labels_from_journal = collections.Counter(
            k for k in got if k[0] in ("/labels", "/events") and k not in expected
        )
        phantom = got - expected - labels_from_journal
        missing = expected - got
        lost_reported = bool([d for d in report.damaged if getattr(d, "lost", True)]) or (
            case.cut is None and not getattr(report, "finished", report.complete)
        )
        if phantom:
            out.phantom += sum(phantom.values())
            out.notes.append(f"recover: {sum(phantom.values())} phantom")
        if missing:
            n = sum(missing.values())
            if lost_reported and not report.complete and case.kind != "cut":
                out.lost_reported += n
            else:
                out.silent_loss += n
                out.notes.append(f"recover: {n} lost silently ({report.reason})")
        try:
            labels = label_keys(work / "out.mcap")
        except Exception as e:  # noqa: BLE001
            out.internal += 1
            out.notes.append(f"labels: {type(e).__name__}: {e}")
            labels = set()
        extra = labels - base.labels
        if extra:
            out.phantom += len(extra)
            out.notes.append(f"recover: {len(extra)} phantom labels")
        wanted = base.journal_labels - labels
        skipped = getattr(report, "journal_skipped", None)
        if wanted and (case.kind == "cut" or (case.kind == "journal" and not skipped)):
            out.silent_loss += len(wanted)
            out.notes.append(f"recover: {len(wanted)} journal labels lost silently")
    if case.kind == "journal":
        return out
    # the reader
    try:
        rec = open_recording(path)
        got = collections.Counter(
            _message_key(m.topic, m.log_time_ns, m.sequence, b"")[:3]
            for m in rec.messages(raw=True)
        )
        want = collections.Counter(k[:3] for k in expected.elements())
        if got - want:
            out.phantom += sum((got - want).values())
            out.notes.append("reader: phantom")
        if want - got:
            out.silent_loss += sum((want - got).values())
            out.notes.append(f"reader: {sum((want - got).values())} lost silently")
    except CaptureError:
        pass
    except Exception as e:  # noqa: BLE001
        out.internal += 1
        out.notes.append(f"reader: {type(e).__name__}: {e}")
    return out


def _records_reported(path: Path, work: Path, out: Outcome) -> None:
    """A flip in a record no MCAP CRC covers: each reader must say so."""
    from capture.errors import CaptureError
    from capture.recording.checking import check
    from capture.recording.reader import open_recording
    from capture.recording.recover import recover

    readers = {
        "check": lambda: bool(check(path).damaged),
        "recover": lambda: not recover(path, work / "r.mcap", overwrite=True).complete,
        "open_recording": lambda: bool(open_recording(path).damaged),
    }
    for name, reported in readers.items():
        try:
            said = reported()
        except CaptureError:
            said = True  # one line: reported
        except Exception as e:  # noqa: BLE001 - what the sweep counts
            out.internal += 1
            out.notes.append(f"{name}: {type(e).__name__}: {e}")
            continue
        if not said:
            out.silent_loss += 1
            out.notes.append(f"{name}: not reported")


def _worker(args):
    base, cases = args
    work = Path(tempfile.mkdtemp(prefix="sweep-"))
    os.environ.setdefault("HOME", str(work))
    try:
        return [(case, run_case(base, case, work)) for case in cases]
    finally:
        shutil.rmtree(work, ignore_errors=True)


def sweep(
    path: Path,
    classes: set[str],
    sample: int | None = None,
    jobs: int = 1,
    every_bit: bool = False,
):
    """{class: (cases, silent losses, phantoms, internal errors, reported losses)} and the
    failing cases."""
    import logging

    before = logging.root.manager.disable
    logging.disable(logging.WARNING)  # every damaged case logs; the counts say it all
    try:
        cases = plan(path, classes, sample, every_bit)
        base = baseline(path, {c.cut for c in cases if c.kind != "cut"})
        batches = [(base, cases[k::jobs]) for k in range(jobs)]
        if jobs > 1:
            import multiprocessing

            with multiprocessing.get_context("fork").Pool(jobs) as pool:
                results = [r for batch in pool.map(_worker, batches) for r in batch]
        else:
            results = _worker(batches[0])
    finally:
        logging.disable(before)  # the process's logging as it was (a test run goes on)
    totals: dict[str, list[int]] = {}
    failing = []
    for case, outcome in results:
        t = totals.setdefault(case.kind, [0, 0, 0, 0, 0])
        t[0] += 1
        t[1] += outcome.silent_loss
        t[2] += outcome.phantom
        t[3] += outcome.internal
        t[4] += outcome.lost_reported
        if outcome.silent_loss or outcome.phantom or outcome.internal:
            failing.append((case, outcome))
    return totals, failing


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.capture.recording.damage_sweep", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("file", type=Path)
    parser.add_argument(
        "--make", action="store_true", help="write a small synthetic recording to FILE first"
    )
    parser.add_argument("--classes", default="opcode,length,summary,journal,cut,records")
    parser.add_argument("--sample", type=int, help="about N cases per class (default: all)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--every-bit", action="store_true", help="all 8 bits of each summary byte")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.make:
        sys.path.insert(0, str(Path(__file__).resolve().parents[3]))  # the checkout: tests.*
        from tests.recording_fixtures import write_recording

        write_recording(args.file, seconds=0.5, chunk_interval_s=0.125)
    classes = set(args.classes.split(","))
    totals, failing = sweep(args.file, classes, args.sample, args.jobs, args.every_bit)
    for case, outcome in failing[:20]:
        print(
            f"FAIL {case.kind} byte {case.offset} bit {case.bit} cut {case.cut} ({case.what}): "
            + "; ".join(outcome.notes)
        )
    columns = ("class", "cases", "silent", "phantom", "internal", "lost, reported")
    print(f"{columns[0]:8} " + " ".join(f"{c:>15}" for c in columns[1:]))
    sums = [0] * 5
    for kind, t in totals.items():
        print(f"{kind:8} " + " ".join(f"{v:15}" for v in t))
        sums = [a + b for a, b in zip(sums, t)]
    print(f"{'total':8} " + " ".join(f"{v:15}" for v in sums))
    if args.json:
        print(
            json.dumps(
                {
                    k: dict(zip(("cases", "silent", "phantom", "internal", "reported"), v))
                    for k, v in totals.items()
                }
            )
        )
    return 1 if any(sums[1:4]) else 0


if __name__ == "__main__":
    sys.exit(main())
