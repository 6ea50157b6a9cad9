"""Fixtures of the terminal UI's tests."""

import asyncio

import pytest


async def _short_idle_wait(min_sleep: float = 0, max_sleep: float = 1) -> None:
    await asyncio.sleep(0.02)


@pytest.fixture
def busy_pilot(monkeypatch):
    """Pilot waits after each key until the process is idle (at most 1 s twice); with a
    live session's capture threads busy in this process it never is: wait briefly instead."""
    monkeypatch.setattr("textual.app.wait_for_idle", _short_idle_wait)
    monkeypatch.setattr("textual.pilot.wait_for_idle", _short_idle_wait)
