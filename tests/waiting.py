"""Waiting for a condition in a test: a generous bound that fails the test, never a
timing claim. `wait_for` polls from the test's thread; `wait_for_app` lets a Textual app
run between looks (the pilot's pauses)."""

from __future__ import annotations

import time
from collections.abc import Callable

DEFAULT_TIMEOUT_S = 30.0


def wait_for(
    condition: Callable[[], object],
    timeout_s: float = DEFAULT_TIMEOUT_S,
    step_s: float = 0.02,
    what: str = "the condition",
) -> float:
    """Seconds until condition() held; AssertionError naming `what` after `timeout_s`."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout_s:
            raise AssertionError(f"{what} not reached within {timeout_s:g} s")
        time.sleep(step_s)
    return time.monotonic() - start


async def wait_for_app(
    pilot,
    condition: Callable[[], object],
    timeout_s: float = 3.0,
    step_s: float = 0.02,
) -> None:
    """Until condition() holds, the app running its messages between looks; fails after
    `timeout_s` worth of the pilot's pauses (counted, so a loaded machine waits longer)."""
    for _ in range(int(timeout_s / step_s)):
        if condition():
            return
        await pilot.pause(step_s)
    assert condition(), f"the app did not reach the condition within {timeout_s:g} s of pauses"
