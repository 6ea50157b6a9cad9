"""The remote control's slots: only trusted connections take them, silent ones wait
outside and time out, and the log says who holds them. Loopback only; no test waits on
a clock, only on the server's state."""

import logging
import os
import socket

import pytest

from capture.labtools import remote as remote_mod
from capture.labtools.remote import MAX_CLIENTS, MAX_PENDING, RemoteControl
from devices.base import DeviceEvent
from tests.waiting import wait_for

HOUR = 3600.0  # a timeout no test reaches: what is shown does not depend on it


class _Controller:
    def __init__(self):
        self.started = []

    def remote_start(self, request):
        self.started.append(request)
        return "recording"

    def remote_stop(self):
        return "saved"


def _connect(remote):
    return socket.create_connection(("127.0.0.1", remote.port), timeout=20)


def _send(sock, line: str) -> bytes:
    sock.sendall(line.encode() + b"\n")
    return sock.recv(16)


def _closed(sock) -> bool:
    try:
        return sock.recv(64) == b""
    except (ConnectionResetError, BrokenPipeError):
        return True


@pytest.mark.parametrize("token", ["", "s3cret"])
def test_a_program_holding_every_connection_cannot_keep_a_trusted_client_out(token):
    controller = _Controller()
    events: list[DeviceEvent] = []
    remote = RemoteControl(
        controller, port=0, on_event=events.append, token=token, auth_timeout_s=HOUR
    ).start()
    squatters = []
    try:
        # more silent connections than there are slots and waiting places together
        for _ in range(MAX_CLIENTS + MAX_PENDING + 4):
            squatters.append(_connect(remote))
        wait_for(lambda: remote.evicted == MAX_CLIENTS + 4, what="the oldest evicted")
        assert remote.slots_taken == 0  # silence takes no slot
        with _connect(remote) as lab:
            if token:
                assert _send(lab, f"token {token}") == b"OK"
            assert _send(lab, "start") == b"OK"
            assert remote.slots_taken == 1
    finally:
        for sock in squatters:
            sock.close()
        remote.close()
    assert len(controller.started) == 1
    assert remote.refused == 0
    assert {e.kind for e in events} == {"evicted"}


def test_a_silent_connection_times_out_and_a_trusted_one_never_does():
    events: list[DeviceEvent] = []
    remote = RemoteControl(
        _Controller(), port=0, on_event=events.append, token="t", auth_timeout_s=0.05
    ).start()
    try:
        with _connect(remote) as lab, _connect(remote) as silent:
            assert _send(lab, "token t") == b"OK"
            assert _closed(silent)  # closed by the server, not by this test
            wait_for(lambda: remote.timed_out == 1)
            assert _send(lab, "update") == b"OK"  # in its slot long past the timeout
            assert remote.connections == 1
    finally:
        remote.close()
    (event,) = events
    assert event.kind == "timeout" and "127.0.0.1:" in event.message


def test_the_log_says_who_holds_the_slots(caplog):
    events: list[DeviceEvent] = []
    caplog.set_level(logging.INFO, logger=remote_mod.__name__)
    remote = RemoteControl(_Controller(), port=0, on_event=events.append).start()
    clients = []
    try:
        for _ in range(MAX_CLIENTS):
            clients.append(_connect(remote))
            assert _send(clients[-1], "update") == b"OK"
        with _connect(remote) as extra:
            extra.sendall(b"update\n")
            assert extra.makefile("rb").read() == remote_mod.BUSY
        clients.pop().close()
        wait_for(lambda: remote.slots_taken == MAX_CLIENTS - 1)
    finally:
        for sock in clients:
            sock.close()
        remote.close()
    text = caplog.text
    assert f"slot 1 of {MAX_CLIENTS} taken by 127.0.0.1:" in text
    assert f"slot {MAX_CLIENTS} of {MAX_CLIENTS} taken by" in text
    assert "slot given back by 127.0.0.1:" in text
    (busy,) = [e for e in events if e.kind == "busy"]
    assert len(busy.details["holders"]) == MAX_CLIENTS
    assert all(h.startswith("127.0.0.1:") for h in busy.details["holders"])
    if os.path.exists("/proc/net/tcp"):  # Linux: the process that holds them, this one
        assert f"pid {os.getpid()}" in busy.message
