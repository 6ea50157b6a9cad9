"""`walkcap imu`: IMU tools: list ports, device info, stream, emulate, decode captures"""

from __future__ import annotations

import json
import math
import os
import sys
import time

from tui.commands import config_value, count, seconds

HELP = "IMU tools: list ports, device info, stream, emulate, decode captures"
_BAUD = config_value("imu.baudrate", int)  # one of the Xsens baud rates

# `decode` keys, in output order (each only when the message has it).
DECODE_KEYS = (
    "packet_counter",
    "sample_time_fine",
    "quaternion",
    "euler",
    "rotation_matrix",
    "acceleration",
    "free_acceleration",
    "delta_v",
    "rate_of_turn",
    "delta_q",
    "magnetic_field",
    "temperature",
    "baro_pressure",
    "status_word",
)


def add_arguments(parser) -> None:
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    verbs.add_parser(
        "list",
        help="serial ports on this machine",
        description="List serial ports (pyserial list_ports).",
    )

    p = verbs.add_parser(
        "info",
        help="device id, product code, firmware, output configuration",
        description="Identify the device on PORT without changing its output configuration.",
    )
    p.add_argument("port", help="serial port, e.g. /dev/ttyUSB0")
    p.add_argument("--baudrate", type=_BAUD, help="default: [imu] baudrate")

    p = verbs.add_parser(
        "set-baud",
        help="change the device's baud rate (it keeps it)",
        description="Set the baud rate of the device on PORT as Xsens' tools do "
        "(SetBaudrate, then a reset). The device keeps it across power cycles; "
        "set [imu] baudrate to the same value.",
    )
    p.add_argument("port", help="serial port, e.g. /dev/ttyUSB0")
    p.add_argument("baud", type=_BAUD, help="the new baud rate, e.g. 460800 or 921600")
    p.add_argument("--baudrate", type=_BAUD, help="its baud rate now (default: [imu] baudrate)")

    p = verbs.add_parser(
        "stream",
        help="live values, rate and errors",
        description="Configure the device on PORT and show live values. "
        "PORT 'mock' streams from an emulator in this process.",
    )
    p.add_argument("port", help="serial port, or 'mock'")
    p.add_argument("--baudrate", type=_BAUD, help="default: [imu] baudrate")
    p.add_argument("--rate", type=count(1, 2000), help="output rate in Hz (default: [imu] rate_hz)")
    p.add_argument("--seconds", type=seconds, help="stop after this long (default: Ctrl-C)")
    p.add_argument("--interval", type=seconds, default=0.5, help="seconds between lines")
    p.add_argument(
        "--raw",
        metavar="FILE",
        help="also save the raw bytes of the serial line (for `walkcap imu decode`)",
    )

    p = verbs.add_parser(
        "emulate",
        help="run the device emulator and print its pty path",
        description="Run the Xsens-style device emulator on a pseudo-terminal "
        "and print its port path, to try the driver or other tools against "
        "it. Ctrl-C stops it.",
    )
    p.add_argument(
        "--rate",
        type=count(1, 2000),
        help="output rate at power-up in Hz (default: [imu] rate_hz)",
    )
    for key, what in (("drift_ppm", "device clock drift"), ("jitter_ms", "transmit jitter")):
        p.add_argument(
            "--" + key.replace("_", "-"),
            type=config_value(f"imu.{key}"),
            help=f"{what} (default: [imu] {key})",
        )
    p.add_argument("--seed", type=int, default=0, help="seed of the emulated motion (default 0)")
    p.add_argument(
        "--model", help="the model it plays, e.g. MTi-3, MTi-630 (default: [imu] emulate)"
    )
    p.add_argument("--baudrate", type=_BAUD, help="its baud rate (default: [imu] baudrate)")
    p.add_argument("--seconds", type=seconds, help="stop after this long (default: Ctrl-C)")

    p = verbs.add_parser(
        "decode",
        help="decode a raw capture of the serial line",
        description="Decode a raw byte capture of the serial line: one JSON "
        "object per MTData2 message, then a summary line (--json), or a "
        "table.",
    )
    p.add_argument("file", help="capture file, '-' for standard input")
    p.add_argument("--json", action="store_true", help="JSON lines instead of a table")

    p = verbs.add_parser(
        "fuzz",
        help="feed the Xbus parser random streams; count exceptions and lost messages",
        description="Feed the Xbus parser STREAMS random byte streams (random MTData2 "
        "layouts, damaged frames, garbage), each followed by valid messages. Reports "
        "exceptions (there must be none) and how often the next valid message was lost to a "
        "false frame that passed the 8-bit checksum. Exit status 1 on any exception.",
    )
    p.add_argument("--streams", type=count(1), default=1_000_000, help="default 1000000")
    p.add_argument("--seed", type=int, default=0, help="the streams' random seed (default 0)")
    p.add_argument("--json", action="store_true", help="machine-readable results")


def run(args, config) -> int:
    return {
        "list": _list,
        "info": _info,
        "set-baud": _set_baud,
        "stream": _stream,
        "emulate": _emulate,
        "decode": _decode,
        "fuzz": _fuzz,
    }[args.verb](args, config)


# ---- list / info ---------------------------------------------------------------------------


def _list(args, config) -> int:
    from serial.tools import list_ports

    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if not ports:
        print("no serial ports found")
        return 0
    for port in ports:
        print(f"{port.device}\t{port.description}\t{port.hwid}")
    return 0


def _baudrate(args, config) -> int:
    """--baudrate, checked as [imu] baudrate is, else the configured one."""
    from capture.config import override

    if args.baudrate is not None:
        override(config, "imu.baudrate", args.baudrate, flag="--baudrate")
    return config.imu.baudrate


def _info(args, config) -> int:
    from devices import xbus
    from devices.imu import XbusImu

    baudrate = _baudrate(args, config)
    imu = XbusImu(args.port, baudrate, outputs=None)
    try:
        imu.open()
    finally:
        imu.close()
    info = imu.info
    print(f"port          {args.port} at {info['baudrate']} baud")
    print(f"device id     {info['device_id']}")
    print(f"product code  {info['product_code']} ({info['family']}, {info['function']})")
    print(f"firmware      {info['firmware']}")
    print("output configuration (stored in the device):")
    for o in info["output_configuration"]:
        extra = " ".join(str(o[k]) for k in ("precision", "coordinate_system") if k in o)
        rate = o["rate_hz"] if isinstance(o["rate_hz"], str) else f"{o['rate_hz']} Hz"
        print(f"  {o['output']:<20} {o['xdi']}  {rate:<14} {extra}".rstrip())
    print(f"link budget   {info['link_budget']}")
    # What a session would ask for: walkcap's outputs at [imu] rate_hz, fitted to the family.
    wanted = xbus.output_settings(xbus.DEFAULT_OUTPUTS, config.imu.rate_hz)
    family = imu.family
    if family is not None:
        wanted = [
            xbus.OutputSetting(s.xdi, family.fit(s.xdi, s.rate_hz))
            for s in wanted
            if family.has(s.name)
        ]
    budget = xbus.link_budget(wanted, baudrate)
    verdict = "fits" if budget.fits else f"does not fit: use {xbus.baud_that_fits(wanted)} baud"
    print(f"session       at {config.imu.rate_hz} Hz: {budget.describe()}: {verdict}")
    if family is not None and not family.has_orientation:
        print("note          an IMU-only model: no orientation, leveling needs a VRU or AHRS")
    return 0


def _set_baud(args, config) -> int:
    from devices.imu import XbusImu

    before = args.baudrate or config.imu.baudrate
    XbusImu(args.port, before, outputs=None).change_baudrate(args.baud)
    print(
        f"IMU on {args.port}: {before} -> {args.baud} baud (kept across power cycles); "
        f"set [imu] baudrate = {args.baud}"
    )
    return 0


# ---- stream --------------------------------------------------------------------------------


def _stream(args, config) -> int:
    from devices.imu import EmulatedImu, XbusImu

    rate = args.rate or config.imu.rate_hz
    baudrate = _baudrate(args, config)
    raw = open(args.raw, "wb") if args.raw else None
    sink = raw.write if raw else None
    if args.port == "mock":
        imu = EmulatedImu(
            rate_hz=rate,
            drift_ppm=config.imu.drift_ppm,
            jitter_ms=config.imu.jitter_ms,
            baudrate=baudrate,
            model=config.imu.emulate,
            raw_sink=sink,
        )
    else:
        imu = XbusImu(args.port, baudrate, rate, raw_sink=sink)
    try:
        with imu:
            info = imu.info
            print(
                f"{info['product_code']} {info['device_id']} firmware {info['firmware']} on "
                f"{imu.port}, {imu.configured_rate_hz:g} Hz (Ctrl-C stops)",
                flush=True,
            )
            _stream_lines(imu, args.seconds, args.interval)
    except KeyboardInterrupt:
        pass
    finally:
        imu.close()
        if raw:
            raw.close()
    return 0


def _stream_lines(imu, seconds: float | None, interval: float) -> None:
    from inference.gait import GaitDetector

    end = time.monotonic() + seconds if seconds is not None else float("inf")
    next_line = time.monotonic() + interval
    last = None
    gait = GaitDetector()  # the thigh's steps, if the IMU is worn on one
    while time.monotonic() < end:
        sample = imu.recv(0.05)
        last = sample or last
        if sample is not None:
            gait.push(sample)
        for event in imu.poll_events():
            print(f"! {event.kind}: {event.message}", flush=True)
        if time.monotonic() >= next_line:
            next_line += interval
            print(_stream_line(last, imu.status(), gait), flush=True)


def gait_text(gait) -> str:
    """Steps counted (two a stride of the thigh) and the cadence, or "still"."""
    cadence = gait.cadence_spm()
    pace = f"{cadence:.0f}/min" if cadence is not None else "still"
    return f"steps {2 * gait.heel_contacts} ({pace})"


def _stream_line(sample, status, gait=None) -> str:
    from devices.imu.clock import drift_text

    d = status.details
    head = (
        f"{status.state:<8} {status.measured_rate_hz:6.1f} Hz  errors {status.errors} "
        f"(crc {d['checksum_errors']}, missing {d['missing_packets']})  "
        f"drift {drift_text(d['drift_ppm'], d.get('drift_uncertainty_ppm'))}  "
        f"jitter {d['residual_ms']:.2f} ms"
    )
    if gait is not None:
        head += "  " + gait_text(gait)
    if sample is None:
        return head
    import numpy as np

    from devices.rotations import quat_to_euler

    parts = [head, f"#{sample.packet_counter}"]
    if sample.quaternion is not None:
        roll, pitch, yaw = np.degrees(quat_to_euler(sample.quaternion))
        parts.append(f"rpy {roll:+6.1f} {pitch:+6.1f} {yaw:+6.1f} deg")
    if sample.acceleration is not None:
        parts.append("acc " + " ".join(f"{v:+6.2f}" for v in sample.acceleration))
    if sample.rate_of_turn is not None:
        parts.append("gyr " + " ".join(f"{v:+5.2f}" for v in sample.rate_of_turn))
    return "  ".join(parts)


# ---- emulate -------------------------------------------------------------------------------


def _emulate(args, config) -> int:
    from devices.errors import DeviceInitError
    from devices.imu.emulator import ImuEmulator

    try:
        emulator = ImuEmulator(
            rate_hz=args.rate or config.imu.rate_hz,
            drift_ppm=config.imu.drift_ppm if args.drift_ppm is None else args.drift_ppm,
            jitter_ms=config.imu.jitter_ms if args.jitter_ms is None else args.jitter_ms,
            seed=args.seed,
            model=args.model or config.imu.emulate,
            baudrate=args.baudrate or config.imu.baudrate,
        )
    except ValueError as e:
        raise DeviceInitError(str(e)) from None
    try:
        port = emulator.start()
        print(port, flush=True)
        print(
            f"IMU emulator ({emulator.product_code}, {emulator.baudrate} baud) at "
            f"{emulator.rate_hz} Hz, drift {emulator.drift_ppm:g} ppm, jitter "
            f"{emulator.jitter_ms:g} ms; try: walkcap imu stream {port}",
            file=sys.stderr,
            flush=True,
        )
        deadline = time.monotonic() + args.seconds if args.seconds is not None else None
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.1 if deadline is None else min(0.1, max(0.0, deadline - time.monotonic())))
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    return 0


# ---- decode --------------------------------------------------------------------------------


def decode_capture(stream, chunk_size: int = 65536):
    """(message dict per MTData2 message ..., then the summary dict) from a byte stream."""
    from devices import xbus

    parser = xbus.XbusParser()
    count = 0
    while True:
        chunk = stream.read(chunk_size)
        messages = parser.feed(chunk) if chunk else parser.finish()
        for msg in messages:
            if msg.mid == xbus.MID.MTDATA2 and msg.mtdata2 is not None:
                count += 1
                yield _plain(
                    {k: msg.mtdata2.values[k] for k in DECODE_KEYS if k in msg.mtdata2.values}
                )
        if not chunk:
            break
    yield {
        "summary": {
            "messages": count,
            "checksum_errors": parser.checksum_errors,
            "resyncs": parser.resyncs,
            "unknown_ids": parser.unknown_ids,
            "malformed": parser.malformed,
        }
    }


def _plain(value):
    """Lists for tuples; None for NaN and infinities, which strict JSON has no word for."""
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _decode(args, config) -> int:
    source = sys.stdin.buffer if args.file == "-" else open(args.file, "rb")
    try:
        if args.json:
            for obj in decode_capture(source):
                print(json.dumps(obj, allow_nan=False))
        else:
            _decode_table(decode_capture(source))
    except BrokenPipeError:  # `walkcap imu decode FILE | head`: the reader has had enough
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    finally:
        if source is not sys.stdin.buffer:
            source.close()
    return 0


def _decode_table(objects) -> None:
    from devices import xbus

    def vec(values, fmt="{:+8.3f}"):
        if values is None:
            return "-"
        return " ".join("nan" if v is None else fmt.format(v) for v in values)

    print(
        f"{'counter':>7} {'time_fine':>10}  {'quaternion w x y z':<35}  "
        f"{'acceleration m/s2':<26}  {'rate of turn rad/s':<26}  {'status':>8}  other"
    )
    for obj in objects:
        if "summary" in obj:
            s = obj["summary"]
            print(
                f"{s['messages']} messages, {s['checksum_errors']} checksum errors, "
                f"{s['resyncs']} resyncs, {s['unknown_ids']} unknown identifiers, "
                f"{s['malformed']} malformed"
            )
            continue
        other = [k for k in obj if k not in xbus.DEFAULT_OUTPUTS]
        status = obj.get("status_word")
        print(
            f"{_or_dash(obj.get('packet_counter')):>7} "
            f"{_or_dash(obj.get('sample_time_fine')):>10}  "
            f"{vec(obj.get('quaternion'), '{:+8.5f}'):<35}  {vec(obj.get('acceleration')):<26}  "
            f"{vec(obj.get('rate_of_turn')):<26}  "
            f"{'-' if status is None else f'0x{status:06X}':>8}  {','.join(other)}"
        )


def _or_dash(value) -> str:
    return "-" if value is None else str(value)


# ---- fuzz ----------------------------------------------------------------------------------


def _fuzz(args, config) -> int:
    from capture.bench.fuzz import fuzz_parser

    say = (lambda line: None) if args.json else (lambda line: print(f"… {line}", file=sys.stderr))
    report = fuzz_parser(args.streams, args.seed, progress=say)
    if args.json:
        print(json.dumps(report.to_dict(), indent=2))
    else:
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(report.by_kind.items()))
        print(f"streams          {report.streams} (seed {report.seed}: {kinds})")
        print(f"exceptions       {report.exceptions}")
        print(
            f"next valid lost  {report.lost_next} "
            f"({report.lost_next / report.streams:.4%}) to a false frame passing the checksum"
        )
        print(f"false frames     {report.false_frames} accepted from damaged or random bytes")
        print(f"malformed        {report.malformed} MTData2 payloads counted and skipped")
        print(f"time             {report.seconds:.1f} s")
        for example in report.examples:
            print(f"  {example}")
    return 1 if report.exceptions else 0
