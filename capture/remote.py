"""Remote control as LabRecorder speaks it, so an experiment script drives walkcap alike.

A TCP server on localhost (LabRecorder's port, 22345, by default) reads one command a line
and answers each with "OK", as LabRecorder does:

    start                       start recording a trial
    stop                        stop it
    filename {root:DIR} {participant:P01} {task:indoor} {run:2} {session:S1} ...
                                what the next trial is: root -> recordings folder,
                                participant -> subject, task -> condition, run -> trial;
                                session, acquisition, modality -> the trial's notes
    update, select all, select none
                                accepted (walkcap records all of its own streams)

What a command does is the `Controller`'s: the headless session's or the terminal UI's,
so the screen always tells the truth.

A command line is at most `MAX_LINE` bytes (LabRecorder's commands are short): a client
that sends more without a newline loses its connection, with one event, before its bytes
cost the session anything.
"""

from __future__ import annotations

import logging
import re
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from capture.errors import CaptureError
from devices.base import DeviceEvent
from devices.clock import now_ns

log = logging.getLogger(__name__)

DEFAULT_PORT = 22345
MAX_LINE = 4096  # bytes of one command line, newline included
_OPTION = re.compile(r"\{(\w+?):([^}]*)\}")


@dataclass
class TrialRequest:
    """What the `filename` commands asked for the next trial (empty: keep the current)."""

    root: str = ""
    subject: str = ""
    condition: str = ""
    trial: int | None = None
    notes: dict = field(default_factory=dict)  # session, acquisition, modality, template


def parse_filename(line: str, request: TrialRequest) -> TrialRequest:
    """Apply LabRecorder's `filename {option:value}...` to `request` (unknown options kept)."""
    for option, value in _OPTION.findall(line):
        option = option.lower()
        if option == "root":
            request.root = value
        elif option == "participant":
            request.subject = value
        elif option == "task":
            request.condition = value
        elif option == "run":
            try:
                request.trial = int(value)
            except ValueError:
                raise CaptureError(
                    f"remote control: run must be a whole number, got {value!r}"
                ) from None
        else:
            request.notes[option] = value
    return request


class Controller(Protocol):
    def remote_start(self, request: TrialRequest) -> str: ...

    def remote_stop(self) -> str: ...


class RemoteControl:
    """The LabRecorder-compatible command server; `port=0` picks a free port."""

    def __init__(
        self,
        controller: Controller,
        port: int = DEFAULT_PORT,
        host: str = "127.0.0.1",
        on_event: Callable[[DeviceEvent], None] | None = None,
    ):
        self.controller = controller
        self._on_event = on_event
        self.request = TrialRequest()
        self.log: list[tuple[str, str]] = []  # (command, what happened), newest last
        self._lock = threading.Lock()
        self._halt = threading.Event()
        try:
            self._server = socket.create_server((host, port))
        except OSError as e:
            raise CaptureError(
                f"remote control: cannot listen on {host}:{port}: {e.strerror} "
                f"(another LabRecorder or walkcap? set [lsl] remote_port)"
            ) from None
        self._server.settimeout(0.2)
        self.port = self._server.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, name="walkcap-remote", daemon=True)

    def start(self) -> RemoteControl:
        self._thread.start()
        return self

    def close(self) -> None:
        self._halt.set()
        self._thread.join(timeout=2.0)
        self._server.close()

    def handle(self, line: str) -> str:
        """One command line; what it did, in words (also logged)."""
        command = line.strip()
        with self._lock:
            try:
                if command == "start":
                    result = self.controller.remote_start(self.request)
                    self.request = TrialRequest(
                        root=self.request.root,
                        subject=self.request.subject,
                        condition=self.request.condition,
                    )
                elif command == "stop":
                    result = self.controller.remote_stop()
                elif command.startswith("filename"):
                    parse_filename(command, self.request)
                    result = f"next trial: {self.request}"
                elif command in ("update", "select all", "select none"):
                    result = "accepted"
                elif not command:
                    return ""
                else:
                    result = f"unknown command {command!r}"
            except CaptureError as e:
                result = f"refused: {e}"
        log.info("remote control: %s -> %s", command, result)
        self.log.append((command, result))
        return result

    def _event(self, kind: str, message: str, details: dict | None = None) -> None:
        log.warning("remote control: %s", message)
        if self._on_event is not None:
            self._on_event(DeviceEvent(now_ns(), "remote", kind, message, details or {}))

    def _serve(self) -> None:
        while not self._halt.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        conn.settimeout(0.5)
        buffer = bytearray()
        with conn:
            while not self._halt.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                searched = len(buffer)  # the buffer before `data` holds no newline
                buffer += data
                while (end := buffer.find(b"\n", searched)) >= 0:
                    line = bytes(buffer[:end])
                    del buffer[: end + 1]
                    searched = 0
                    self.handle(line.decode("utf-8", "replace"))
                    try:
                        conn.sendall(b"OK")  # LabRecorder answers every line so
                    except OSError:
                        return
                if len(buffer) >= MAX_LINE:
                    self._event(
                        "line_too_long",
                        f"a command line over {MAX_LINE} bytes: connection closed",
                        {"limit_bytes": MAX_LINE},
                    )
                    return
