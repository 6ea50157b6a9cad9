"""Remote control (LabRecorder's commands) and the live Foxglove server, on loopback."""

import asyncio
import base64
import json
import logging
import socket
import struct
import threading
import time

import numpy as np
import pytest

from capture.config import Config
from capture.labtools.connections import LabTools, SessionController
from capture.labtools.foxglove_live import LAYOUT, FoxgloveLive
from capture.labtools.lsl import LslOutlets
from capture.labtools.remote import MAX_CLIENTS, RemoteControl, TrialRequest, parse_filename
from capture.live.session import Session
from capture.live.trials import SubjectInfo
from capture.recording import topics as T
from capture.recording.reader import open_recording
from capture.recording.sink import Sink
from devices.base import DeviceEvent
from devices.frames import GaitEvent, ImuSample
from devices.simulator.synthetic import synthetic_frame
from tests.waiting import wait_for


def test_filename_options_map_onto_the_trial():
    request = parse_filename(
        "filename {root:/data/study} {template:exp%n/block_%b.xdf} {participant:P07} "
        "{task:stairs} {run:3} {session:S2} {acquisition:a}",
        TrialRequest(),
    )
    assert (request.root, request.subject, request.condition, request.trial) == (
        "/data/study",
        "P07",
        "stairs",
        3,
    )
    assert request.notes == {"template": "exp%n/block_%b.xdf", "session": "S2", "acquisition": "a"}


def _send(sock: socket.socket, line: str) -> bytes:
    sock.sendall(line.encode() + b"\n")
    return sock.recv(16)


@pytest.mark.realtime
def test_remote_commands_start_and_stop_a_recording(tmp_path):
    cfg = Config()
    cfg.session.recordings = str(tmp_path / "unused")
    cfg.simulator.realtime = False  # as fast as the pipeline: no real time to wait for
    cfg.simulator.loop = True
    session = Session(cfg, auto_label=True)
    session.start()
    remote = RemoteControl(SessionController(session, SubjectInfo()), port=0).start()
    try:
        with socket.create_connection(("127.0.0.1", remote.port), timeout=5) as sock:
            assert _send(sock, "select all") == b"OK"
            reply = _send(
                sock, f"filename {{root:{tmp_path}}} {{participant:P07}} {{task:stairs}} {{run:3}}"
            )
            assert reply == b"OK"
            assert _send(sock, "start") == b"OK"
            deadline = time.monotonic() + 5
            while session.snapshot().frames < 10 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert session.recording
            assert _send(sock, "stop") == b"OK"
            assert not session.recording
    finally:
        remote.close()
        session.stop()
    (path,) = tmp_path.glob("P07_stairs_t03_*.mcap")
    meta = open_recording(path).metadata["session"]
    assert meta["subject"] == "P07" and meta["condition"] == "stairs"
    assert [r for _, r in remote.log][-1].startswith("saved ")


def test_a_port_in_use_is_one_clear_error():
    from capture.errors import CaptureError

    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        with pytest.raises(CaptureError, match=f"cannot listen on 127.0.0.1:{port}"):
            RemoteControl(SessionController(None, SubjectInfo()), port=port)


# ---- Foxglove -----------------------------------------------------------------------------


async def _subscribe_all(url: str, fox: FoxgloveLive, publish) -> tuple[dict, dict]:
    import websockets

    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        channels = {}
        deadline = time.monotonic() + 5
        while len(channels) < len(T.TOPICS) and time.monotonic() < deadline:
            msg = await asyncio.wait_for(ws.recv(), 5)
            if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                for ch in json.loads(msg)["channels"]:
                    channels[ch["topic"]] = ch
        subs = [{"id": i, "channelId": ch["id"]} for i, ch in enumerate(channels.values())]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
        by_sub = {s["id"]: ch["topic"] for s, ch in zip(subs, channels.values())}
        while sum(fox._subscriptions.count.values()) < len(subs):
            await asyncio.sleep(0.02)
        publish()
        got: dict[str, bytes] = {}
        deadline = time.monotonic() + 10
        while len(got) < len(channels) - 1 and time.monotonic() < deadline:  # no /camera/gray
            try:
                msg = await asyncio.wait_for(ws.recv(), 1)
            except TimeoutError:
                continue
            if isinstance(msg, bytes) and msg[0] == 0x01:
                sub_id, _ = struct.unpack_from("<IQ", msg, 1)
                got.setdefault(by_sub[sub_id], msg[13:])
        return channels, got


def _decode(channel: dict, payload: bytes):
    if channel["encoding"] == "json":
        import jsonschema

        message = json.loads(payload)
        jsonschema.validate(message, json.loads(channel["schema"]))
        return message
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    schema = Schema(
        id=1,
        name=channel["schemaName"],
        encoding=channel["schemaEncoding"],
        data=base64.b64decode(channel["schema"]),
    )
    return DecoderFactory().decoder_for("protobuf", schema)(payload)


def test_foxglove_server_publishes_every_topic_with_the_recordings_schemas():
    fox = FoxgloveLive(port=0, image_hz=0)
    frame = synthetic_frame(3, 1_000_000_000)
    frame.truth = {"mode": "LG"}
    t = frame.device_time_ns

    def publish():
        fox.write_frame(frame, t)
        image = np.zeros((100, 100), np.uint8)
        image[80:, :] = 1
        cloud = np.array([[0.5, 0.0, 0.0], [0.6, 0.0, 0.01]], np.float32)
        fox.write_processed(3, t, t, cloud, image, np.array([1.0, 0, 0, 0]), "")
        fused = {"frame_index": 1, "decision": "LG", "posterior": [0.2] * 5, "voted": None}
        fox.write_inference(3, t, t, np.full(5, 0.2), fused)
        fox.write_features(3, t, {"slope_deg": 0.5})
        fox.write_truth(3, t, frame.truth)
        fox.write_gait(GaitEvent(t, "heel_contact", "imu"), t)
        fox.write_gait(GaitEvent(t, "heel_contact", "simulator", "LG"))
        fox.write_imu(ImuSample(host_time_ns=t, time_ns=t, quaternion=np.array([1.0, 0, 0, 0])))
        fox.write_label(t, "LG", "operator")
        fox.write_event(DeviceEvent(t, "operator", "marker", "start"))

    try:
        channels, got = asyncio.run(_subscribe_all(fox.url, fox, publish))
    finally:
        fox.close()
    for topic in T.TOPICS:
        spec = T.TOPICS[topic]
        assert channels[topic]["schemaName"] == spec.schema_name  # the recording's schemas
        assert channels[topic]["encoding"] == spec.message_encoding
    assert set(got) == set(T.TOPICS) - {T.GRAY}
    decoded = {topic: _decode(channels[topic], payload) for topic, payload in got.items()}
    assert decoded[T.DEPTH].width == frame.geometry.width
    assert decoded[T.LABELS]["mode"] == "LG"
    assert decoded[T.CNN]["frame_index"] == 3
    assert decoded[T.EVENTS]["message"] == "start"
    assert decoded[T.SIM_GAIT]["mode"] == "LG"


def test_the_shipped_layout_names_only_walkcaps_topics():
    layout = json.loads(LAYOUT.read_text())
    text = json.dumps(layout["configById"])
    named = {t for t in T.TOPICS if f'"{t}' in text or f"{t}." in text}
    assert {T.DEPTH, T.BINARY_IMAGE, T.CLOUD, T.CNN, T.LABELS, T.FUSED} <= named
    panels = {key.split("!")[0] for key in layout["configById"]}
    assert panels <= {"Image", "3D", "Plot", "StateTransitions", "RawMessages"}


# ---- remote control facing a misbehaving local program ------------------------------------


class _Controller:
    def __init__(self) -> None:
        self.started: list[TrialRequest] = []

    def remote_start(self, request: TrialRequest) -> str:
        self.started.append(request)
        return "recording"

    def remote_stop(self) -> str:
        return "saved"


def _misbehaving_client(payload: bytes) -> tuple:
    """What a client sending `payload` reads back before its connection is closed, the
    events that caused, and the remote's command log; the next client is served as ever."""
    events: list[DeviceEvent] = []
    remote = RemoteControl(_Controller(), port=0, on_event=events.append).start()
    try:
        with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
            try:
                sock.sendall(payload)
                answers = sock.makefile("rb").read()  # until the remote closes
            except (ConnectionResetError, BrokenPipeError):
                answers = b""
        wait_for(lambda: events)
        with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
            assert _send(sock, "update") == b"OK"
    finally:
        remote.close()
    return answers, events, remote.log


def test_an_over_long_line_closes_its_connection_with_one_event():
    answers, events, _ = _misbehaving_client(b"x" * (4 << 20))  # 4 MB, no newline
    assert answers == b""
    assert [e.kind for e in events] == ["line_too_long"]
    assert events[0].device == "remote"


def test_connections_beyond_the_slots_are_refused_politely_by_one_thread():
    events: list[DeviceEvent] = []
    threads_before = threading.active_count()
    remote = RemoteControl(_Controller(), port=0, on_event=events.append).start()
    idle: list[socket.socket] = []
    try:
        for _ in range(MAX_CLIENTS):
            idle.append(socket.create_connection(("127.0.0.1", remote.port), timeout=20))
            assert _send(idle[-1], "update") == b"OK"  # the first ones are served
        answers = []
        for _ in range(50):
            with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as extra:
                extra.sendall(b"update\n")
                answers.append(extra.makefile("rb").read())  # one line, then closed
        assert set(answers) == {
            b"busy: walkcap takes %d remote-control connections at a time\n" % MAX_CLIENTS
        }
        assert threading.active_count() <= threads_before + 1  # one thread serves them all
        assert remote.refused == 50
        for sock in idle:
            sock.close()
        idle.clear()
        wait_for(lambda: remote.connections == 0)
        with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
            assert _send(sock, "update") == b"OK"  # room again once they are gone
    finally:
        for sock in idle:
            sock.close()
        remote.close()
    assert [e.kind for e in events] == ["busy"]  # reaching the limit: one event


def _lab_session(recordings):
    cfg = Config()
    cfg.session.recordings = str(recordings)
    cfg.simulator.realtime = False
    cfg.simulator.loop = True
    cfg.lsl.remote_control = True
    cfg.lsl.remote_port = 0
    session = Session(cfg, auto_label=True)
    session.start()
    lab = LabTools(session, cfg, SessionController(session, SubjectInfo())).start()
    assert lab.remote is not None, lab.problems
    return cfg, session, lab


def _remote_events(session) -> list[DeviceEvent]:
    return [e for e in session.snapshot().events if e.device == "remote"]


@pytest.mark.realtime
def test_a_remote_root_is_the_remote_trials_only_and_bad_commands_are_one_event_each(
    tmp_path, capfd
):
    recordings = tmp_path / "recordings"
    cfg, session, lab = _lab_session(recordings)
    try:
        with socket.create_connection(("127.0.0.1", lab.remote.port), timeout=20) as sock:
            bad = [
                "filename {root:x\x00y}",  # a NUL in the folder
                "filename {root:/proc/1/nope}",  # outside the recordings folder
                "filename {root:../elsewhere}",
                "filename {run:99999999999999999999}",
                "filename {participant:../P07}",
                "frobnicate \x1b[2J",
            ]
            for line in bad:
                assert _send(sock, line) == b"OK"  # answered as LabRecorder answers
            wait_for(lambda: len(_remote_events(session)) == len(bad))
            assert {e.kind for e in _remote_events(session)} == {"refused"}
            line = "filename {root:study} {participant:P07} {task:stairs} {run:2}"
            assert _send(sock, line) == b"OK"
            assert _send(sock, "start") == b"OK"
            wait_for(lambda: session.snapshot().frames >= 10)
            assert _send(sock, "stop") == b"OK"
        assert cfg.session.recordings == str(recordings)  # the operator's folder as it was
        local = session.start_recording(SubjectInfo(subject="OP1"))
        session.stop_recording()
    finally:
        lab.stop()
        session.stop()
    assert len(_remote_events(session)) == len(bad)  # one event each, nothing more
    (remote_trial,) = (recordings / "study").glob("P07_stairs_t02_*.mcap")
    assert local.parent == recordings
    trials = {str(p.relative_to(recordings)).split(".mcap")[0] for p in recordings.rglob("*.*")}
    assert trials == {str(p.relative_to(recordings))[:-5] for p in (remote_trial, local)}
    assert not (tmp_path / "elsewhere").exists()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "\x1b" not in err


def test_with_a_shared_token_only_a_connection_that_gives_it_is_obeyed():
    events: list[DeviceEvent] = []
    controller = _Controller()
    remote = RemoteControl(controller, port=0, on_event=events.append, token="s3cret").start()
    try:
        for first in ("start", "token wrong"):
            with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
                sock.sendall(first.encode() + b"\n")
                assert sock.makefile("rb").read() == b""  # closed, unanswered
        with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
            assert _send(sock, "token s3cret") == b"OK"
            assert _send(sock, "start") == b"OK"
    finally:
        remote.close()
    assert len(controller.started) == 1
    assert [e.kind for e in events] == ["unauthorized", "unauthorized"]
    assert all("s3cret" not in command for command, _ in remote.log)


CONTROL = "\x1b]0;owned\x07\x1b[2J\x1b[31mFAKE: recording stopped\u202e"


def _raw_control(text: str) -> bool:
    return any(not ch.isprintable() for ch in text)


def test_repeated_bad_commands_are_escaped_and_counted_not_flooded():
    events: list[DeviceEvent] = []
    remote = RemoteControl(_Controller(), port=0, on_event=events.append).start()
    try:
        with socket.create_connection(("127.0.0.1", remote.port), timeout=20) as sock:
            stream = sock.makefile("rb")
            sock.sendall((CONTROL + "\n").encode() * 100)
            assert stream.read(2 * 100) == b"OK" * 100  # every line answered
    finally:
        remote.close()
    counts = [e.details.get("count") for e in events]
    assert counts == [None] * 10 + [100]  # the first ten, then the hundredth with its count
    assert not any(_raw_control(e.message) for e in events)
    assert "\\x1b]0;owned\\x07" in events[0].message  # shown, escaped


def test_foxglove_client_text_is_escaped_and_its_repeats_counted(caplog):
    import websockets

    fox = FoxgloveLive(port=0)

    async def misbehave():
        async with websockets.connect(fox.url, subprotocols=["foxglove.sdk.v1"]) as ws:
            await ws.send(json.dumps({"op": CONTROL}))
            subs = [{"id": i, "channelId": 10_000_000 + i} for i in range(20_000)]
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            deadline = time.monotonic() + 60
            while fox.client_messages < 20_001 and time.monotonic() < deadline:
                await asyncio.sleep(0.05)

    caplog.set_level(logging.WARNING)
    try:
        asyncio.run(misbehave())
        assert fox.client_messages >= 20_001  # each seen, and counted
    finally:
        fox.close()
    lines = [r.getMessage() for r in caplog.records]
    assert not any(_raw_control(line) for line in lines)
    assert any("\\x1b]0;owned\\x07" in line for line in lines)
    assert len(lines) <= 20  # the first few, the powers of ten, the tally at close
    assert "not shown" in lines[-1]


def test_a_flood_of_commands_closes_its_connection_with_one_event():
    from capture.labtools.remote import COMMAND_BURST

    answers, events, log = _misbehaving_client(b"update\n" * 100_000)
    assert len(answers) < 2 * 100_000  # closed long before the last
    assert COMMAND_BURST <= len(log) < 100_000
    assert [e.kind for e in events] == ["flood"]


def test_the_live_taps_are_sinks():
    """The session hands every tap every write (Sink); a tap overrides what it carries."""
    assert issubclass(FoxgloveLive, Sink) and issubclass(LslOutlets, Sink)
    assert LslOutlets.write_frame is Sink.write_frame  # an outlet carries no depth
    assert FoxgloveLive.write_frame is not Sink.write_frame
