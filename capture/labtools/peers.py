"""Who is at the other end of a loopback TCP connection: its address, and on Linux the
user and process that hold the socket (from /proc), so that a log can say who holds the
remote control's slots. Best effort: what cannot be read is left out, never an error."""

from __future__ import annotations

import os
import socket
from pathlib import Path

_PROC = Path("/proc")


def peer_address(conn: socket.socket) -> tuple[str, int] | None:
    """The connection's far end (host, port); None once it is gone."""
    try:
        host, port = conn.getpeername()[:2]
    except OSError:
        return None
    return host, port


def describe(address: tuple[str, int] | None) -> str:
    """`127.0.0.1:40522 (uid 1000, pid 4242 python3)`, as much of it as can be found (a
    look through /proc: for log lines, not for every connection)."""
    if address is None:
        return "a closed connection"
    host, port = address
    owner = _owner(host, port)
    return f"{host}:{port}" + (f" ({owner})" if owner else "")


def _owner(host: str, port: int) -> str:
    try:
        uid, inode = _socket_inode(host, port)
    except (OSError, ValueError):
        return ""
    if inode is None:
        return ""
    parts = [f"uid {uid}"]
    pid = _pid_of(inode)
    if pid is not None:
        try:
            name = (_PROC / str(pid) / "comm").read_text().strip()
        except OSError:
            name = ""
        parts.append(f"pid {pid} {name}".strip())
    return ", ".join(parts)


def _socket_inode(host: str, port: int) -> tuple[int, int | None]:
    """(uid, inode) of the IPv4 socket whose local address is host:port (the peer's end)."""
    want = f"{socket.inet_aton(host)[::-1].hex().upper()}:{port:04X}"
    with open(_PROC / "net" / "tcp") as table:
        next(table)  # the header
        for line in table:
            fields = line.split()
            if len(fields) > 9 and fields[1] == want:
                return int(fields[7]), int(fields[9])
    return -1, None


def _pid_of(inode: int) -> int | None:
    """The process holding the socket, among those this user may look into."""
    target = f"socket:[{inode}]"
    for entry in _PROC.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            for fd in (entry / "fd").iterdir():
                if os.readlink(fd) == target:
                    return int(entry.name)
        except OSError:
            continue
    return None
