"""Remote control as LabRecorder speaks it, so an experiment script drives walkcap alike.

A TCP server on localhost (LabRecorder's port, 22345, by default) reads one command a line
and answers each with "OK", as LabRecorder does:

    start                       start recording a trial
    stop                        stop it
    filename {root:DIR} {participant:P01} {task:indoor} {run:2} {session:S1} ...
                                what the next remote trial is: root -> its folder,
                                participant -> subject, task -> condition, run -> trial;
                                session, acquisition, modality -> the trial's notes
    update, select all, select none
                                accepted (walkcap records all of its own streams)

What a command does is the `Controller`'s: the headless session's or the terminal UI's,
so the screen always tells the truth. A command refused (unknown, a bad value, a root the
`check` refuses, a start the session refuses) is answered "OK" all the same, as LabRecorder
answers every line, and is one event (a kind of event that repeats is counted:
capture.labtools.safetext.Repeats). Client text is escaped before it is logged or put into an
event (capture.labtools.safetext.escape). With a `token`, a connection's first line must be
`token <it>`; any other first line closes the connection with one event.

One thread serves every client (a selector loop). A connection takes one of the
`MAX_CLIENTS` slots only once it is trusted: with its first line, which with a token must
be `token <it>`. Until then it waits outside the slots, at most `AUTH_TIMEOUT_S` (then it
is closed, one event) and at most `MAX_PENDING` of them (one more closes the oldest), so
a program that opens connections and never speaks cannot keep the lab's LabRecorder out.
A trusted connection beyond the slots is told so in one line and closed; reaching the
limit is one event naming who holds the slots (capture.labtools.peers), and each slot
taken and given back is a log line naming its holder. A connection
that sends more than COMMAND_BURST commands at once (COMMANDS_PER_S a second on) is
closed with one event. A command line
is at most `MAX_LINE` bytes (LabRecorder's commands are short): a client that sends more
without a newline loses its connection, with one event, before its bytes cost the session
anything.
"""

from __future__ import annotations

import dataclasses
import hmac
import logging
import re
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from capture.errors import CaptureError
from capture.labtools import peers
from capture.labtools.safetext import Repeats, escape
from devices.base import DeviceEvent
from devices.clock import now_ns

log = logging.getLogger(__name__)
_PARTICIPANT = re.compile(r"\{participant:[^}]*\}")

DEFAULT_PORT = 22345
MAX_LINE = 4096  # bytes of one command line, newline included
MAX_CLIENTS = 8  # an experiment script holds one; a few more for tools beside it
BUSY = b"busy: walkcap takes %d remote-control connections at a time\n" % MAX_CLIENTS
# Connections not yet trusted: LabRecorder's clients speak at once, so a few seconds and a
# few dozen are plenty; the oldest gives way to a new one, so none of them blocks a client.
AUTH_TIMEOUT_S = 5.0
MAX_PENDING = 32
# Commands of one connection: a script sends a few a trial; a flood of short lines would
# hold the interpreter the pipeline shares, so beyond these the connection is closed.
COMMAND_BURST = 100
COMMANDS_PER_S = 20.0
EVENT_BURST = 10  # events of one kind shown before only every power of ten is
LOG_ENTRIES = 1000  # the newest commands kept in `log`
MAX_RUN = 9999
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
            if not value.isprintable():
                raise CaptureError("root: a folder name without control characters")
            request.root = value
        elif option == "participant":
            request.subject = value
        elif option == "task":
            request.condition = value
        elif option == "run":
            if not re.fullmatch(r"[0-9]{1,9}", value.strip()) or not 1 <= int(value) <= MAX_RUN:
                raise CaptureError(f"run: a whole number from 1 to {MAX_RUN}, got {value!r}")
            request.trial = int(value)
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
        *,
        on_event: Callable[[DeviceEvent], None] | None = None,
        check: Callable[[TrialRequest], TrialRequest] | None = None,
        token: str = "",
        auth_timeout_s: float = AUTH_TIMEOUT_S,
    ):
        self.controller = controller
        self._on_event = on_event
        self._check = check  # a `filename`'s request as the session takes it, or CaptureError
        self._token = token.encode()
        self._auth_timeout_s = auth_timeout_s
        self.request = TrialRequest()
        # (command, what happened), newest last; a flood of commands keeps the newest
        self.log: deque[tuple[str, str]] = deque(maxlen=LOG_ENTRIES)
        self.saved: list[str] = []  # the files remote trials were saved to
        self._lock = threading.Lock()
        self._halt = threading.Event()
        self.refused = 0  # trusted connections turned away: every slot was taken
        self.timed_out = 0  # connections closed before their first line came in time
        self.evicted = 0  # waiting connections closed to make room for a new one
        self._repeats = Repeats(burst=EVENT_BURST)
        try:
            self._server = socket.create_server((host, port), backlog=128)
        except OSError as e:
            raise CaptureError(
                f"remote control: cannot listen on {host}:{port}: {e.strerror} "
                f"(another LabRecorder or walkcap? set [lsl] remote_port)"
            ) from None
        self._server.setblocking(False)
        self.port = self._server.getsockname()[1]
        self._wake, self._waker = socket.socketpair()  # close() wakes the selector loop
        self._clients: dict[socket.socket, _Client] = {}
        self._full = False
        self._thread = threading.Thread(target=self._serve, name="walkcap-remote", daemon=True)

    @property
    def connections(self) -> int:
        """Clients connected now, in a slot or waiting for their first line."""
        return len(self._clients)

    @property
    def slots_taken(self) -> int:
        """Clients in a slot: trusted, commands obeyed."""
        return sum(1 for c in list(self._clients.values()) if c.slot)

    def holders(self) -> list[str]:
        """Who holds the slots, one description each (address, user, process)."""
        return [c.who() for c in list(self._clients.values()) if c.slot]

    def start(self) -> RemoteControl:
        self._thread.start()
        return self

    def close(self) -> None:
        self._halt.set()
        try:
            self._waker.send(b"x")
        except OSError:
            pass
        self._thread.join(timeout=2.0)
        self._server.close()
        self._wake.close()
        self._waker.close()

    def handle(self, line: str) -> str:
        """One command line; what it did, in words (also logged; a refusal is an event)."""
        command = line.strip()
        if not command:
            return ""
        refused = False
        with self._lock:
            try:
                result = self._command(command)
            except CaptureError as e:
                result, refused = f"refused: {e}", True
            except Exception as e:  # a command never takes the server down
                log.debug("remote control: %s", escape(command, 80), exc_info=True)
                result, refused = f"refused: {type(e).__name__}: {e}", True
            if result.startswith("saved "):
                self.saved.append(result.removeprefix("saved "))
        command, result = self._hidden(command), self._hidden(result)
        # the client's text, fit for a terminal; a refused command's participant may be a
        # name: it stays out of the log and the recording's events
        shown = escape(_PARTICIPANT.sub("{participant:…}", command) if refused else command, 80)
        log.info("remote control: %s -> %s", shown, escape(result))
        self.log.append((command, result))
        if refused:
            self._event("refused", f"{shown} -> {escape(result)}", {"command": shown})
        return result

    def _hidden(self, text: str) -> str:
        """`text` without the token, nor whatever follows a `token` word (a mistyped token
        is nearly the token): for the log, the events, the screen and the recording."""
        if text.split(maxsplit=1)[:1] == ["token"]:
            text = "token <secret>"
        token = self._token.decode("utf-8", "replace")
        return text.replace(token, "<secret>") if token else text

    def _command(self, command: str) -> str:
        if command == "start":
            result = self.controller.remote_start(self.request)
            self.request = TrialRequest(
                root=self.request.root,
                subject=self.request.subject,
                condition=self.request.condition,
            )
            return result
        if command == "stop":
            return self.controller.remote_stop()
        if command.split(maxsplit=1)[0] == "filename":
            # on a copy: a refused filename leaves the next trial as it was
            request = dataclasses.replace(self.request, notes=dict(self.request.notes))
            request = parse_filename(command, request)
            if self._check is not None:
                request = self._check(request)
            self.request = request
            return f"next trial: {request}"
        if command in ("update", "select all", "select none"):
            return "accepted"
        raise CaptureError("unknown command")

    def _event(
        self, kind: str, message: str | Callable[[], str], details: dict | None = None
    ) -> None:
        """One event and log line; a kind that repeats is counted, and shown at the first
        EVENT_BURST and then at each power of ten with its count. A callable message is
        made only when shown (it may look up who a peer is)."""
        show, n = self._repeats.check(kind)
        if not show:
            return
        if callable(message):
            message = message()
        details = dict(details or {})
        if n > self._repeats.burst:
            message = f"{message} ({n} like it so far)"
            details["count"] = n
        log.warning("remote control: %s", message)
        if self._on_event is not None:
            self._on_event(DeviceEvent(now_ns(), "remote", kind, message, details))

    def _serve(self) -> None:
        selector = selectors.DefaultSelector()
        selector.register(self._server, selectors.EVENT_READ)
        selector.register(self._wake, selectors.EVENT_READ)
        try:
            while not self._halt.is_set():
                for key, _ in selector.select(self._expire(selector)):
                    if key.fileobj is self._server:
                        self._accept(selector)
                    elif key.fileobj is not self._wake:
                        self._read(selector, key.data)
        except Exception:  # the server stops; the session never does
            log.exception("remote control")
        finally:
            for client in list(self._clients.values()):
                self._drop(selector, client)
            selector.close()

    def _accept(self, selector: selectors.BaseSelector) -> None:
        while True:
            try:
                conn, _ = self._server.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # the client gave up before it was accepted
                return
            conn.setblocking(False)
            waiting = [c for c in self._clients.values() if not c.slot]
            if len(waiting) >= MAX_PENDING:  # the oldest silent one gives way
                self.evicted += 1
                oldest = min(waiting, key=lambda c: c.since)
                self._event(
                    "evicted",
                    lambda oldest=oldest: (
                        f"{MAX_PENDING} connections waiting for their first line: "
                        f"the oldest closed ({oldest.who()})"
                    ),
                    {"limit": MAX_PENDING},
                )
                self._drop(selector, oldest)
            client = _Client(conn, trusted=not self._token, now=time.monotonic())
            self._clients[conn] = client
            selector.register(conn, selectors.EVENT_READ, client)

    def _expire(self, selector: selectors.BaseSelector) -> float | None:
        """Close the connections whose first line is overdue; seconds to the next due."""
        now = time.monotonic()
        due = None
        for client in list(self._clients.values()):
            if client.slot:
                continue
            left = client.since + self._auth_timeout_s - now
            if left <= 0:
                self.timed_out += 1
                self._event(
                    "timeout",
                    lambda client=client: (
                        f"a connection silent for {self._auth_timeout_s:g} s "
                        f"before its first line: closed ({client.who()})"
                    ),
                    {"timeout_s": self._auth_timeout_s},
                )
                self._drop(selector, client)
            else:
                due = left if due is None else min(due, left)
        return due

    def _take_slot(self, selector: selectors.BaseSelector, client: _Client) -> bool:
        """A slot for a trusted client, or the busy line and the connection closed."""
        taken = self.slots_taken
        if taken >= MAX_CLIENTS:
            self.refused += 1
            try:
                client.conn.send(BUSY)
            except OSError:
                pass
            if not self._full:  # once each time the limit is reached
                self._full = True
                self._event(
                    "busy",
                    f"all {MAX_CLIENTS} slots taken, further connections refused; "
                    f"held by {', '.join(self.holders())}",
                    {"limit": MAX_CLIENTS, "holders": self.holders()},
                )
            self._drop(selector, client)
            return False
        client.slot = True
        log.info("remote control: slot %d of %d taken by %s", taken + 1, MAX_CLIENTS, client.who())
        return True

    def _trust(self, line: bytes) -> bool:
        """Whether `line` is `token <the token>` (compared in constant time)."""
        word, _, given = line.strip().partition(b" ")
        return word == b"token" and hmac.compare_digest(given.strip(), self._token)

    def _drop(self, selector: selectors.BaseSelector, client: _Client) -> None:
        if self._clients.pop(client.conn, None) is not None and client.slot:
            log.info("remote control: slot given back by %s", client.who())
        try:
            selector.unregister(client.conn)
        except (KeyError, ValueError):
            pass
        client.conn.close()
        if self.slots_taken < MAX_CLIENTS:
            self._full = False

    def _read(self, selector: selectors.BaseSelector, client: _Client) -> None:
        try:
            data = client.conn.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(selector, client)
            return
        buffer = client.buffer
        searched = len(buffer)  # the buffer before `data` holds no newline
        buffer += data
        while (end := buffer.find(b"\n", searched)) >= 0:
            line = bytes(buffer[:end])
            del buffer[: end + 1]
            searched = 0
            if not client.allow(time.monotonic()):
                self._event(
                    "flood",
                    f"more than {COMMAND_BURST} commands at once "
                    f"({COMMANDS_PER_S:g} a second on): connection closed",
                    {"burst": COMMAND_BURST, "per_s": COMMANDS_PER_S},
                )
                self._drop(selector, client)
                return
            if not client.trusted:
                if not self._trust(line):
                    self._event(
                        "unauthorized",
                        lambda: f"a connection without the token: closed ({client.who()})",
                    )
                    self._drop(selector, client)
                    return
                client.trusted = True
                if not self._take_slot(selector, client):
                    return
            else:
                if not client.slot and not self._take_slot(selector, client):
                    return
                self.handle(line.decode("utf-8", "replace"))
            try:  # LabRecorder answers every line so
                sent = client.conn.send(b"OK")
            except OSError:
                sent = 0
            if sent != 2:  # gone, or not reading its answers: it takes no more of the loop
                self._drop(selector, client)
                return
        if len(buffer) >= MAX_LINE:
            self._event(
                "line_too_long",
                f"a command line over {MAX_LINE} bytes: connection closed",
                {"limit_bytes": MAX_LINE},
            )
            self._drop(selector, client)


class _Client:
    """One connection and the part of a line it has sent so far."""

    __slots__ = (
        "address", "buffer", "conn", "credit", "credit_at", "described", "since", "slot", "trusted"
    )  # fmt: skip

    def __init__(self, conn: socket.socket, trusted: bool, now: float) -> None:
        self.conn = conn
        self.buffer = bytearray()
        self.trusted = trusted  # no token asked for, or it was given
        self.slot = False  # holds one of the MAX_CLIENTS slots (trusted, has spoken)
        self.since = now  # accepted at (monotonic s): its first line is due by the timeout
        self.address = peers.peer_address(conn)
        self.described = ""
        self.credit = float(COMMAND_BURST)  # commands it may send now (a token bucket)
        self.credit_at = now

    def who(self) -> str:
        """Its address, user and process (looked up once, when first asked)."""
        if not self.described:
            self.described = peers.describe(self.address)
        return self.described

    def allow(self, now: float) -> bool:
        """Whether one more command is within COMMAND_BURST and COMMANDS_PER_S."""
        self.credit = min(COMMAND_BURST, self.credit + (now - self.credit_at) * COMMANDS_PER_S)
        self.credit_at = now
        if self.credit < 1.0:
            return False
        self.credit -= 1.0
        return True
