"""Helpers for driving the terminal UI in tests: the terminal size, the way to the live
screen, what a screen or widget shows as text, and stand-ins for the classifier and clock."""

import contextlib

import numpy as np

from capture.live.trials import SubjectInfo
from tests.waiting import wait_for_app
from tui.live_screen import LiveScreen
from tui.session_screen import SessionScreen

SIZE = (120, 40)
# A subject with every field of the session form filled (an amputee: side and limb too).
FILLED_SUBJECT = SubjectInfo(
    subject="A01",
    height_m=1.72,
    weight_kg=70.0,
    age=52,
    sex="female",
    amputee=True,
    side="left",
    residual_limb_cm=31.0,
    condition="indoor",
    trial=2,
)


@contextlib.asynccontextmanager
async def live_app(config=None, **kw):
    """The app on a FakeSession with its live screen open: (app, fake, pilot, live)."""
    from capture.config import Config
    from tests.tui_fake_session import FakeSession
    from tui.app import WalkcapApp

    fake = FakeSession()
    app = WalkcapApp(config or Config(), session=fake, **kw)
    async with app.run_test(size=SIZE) as pilot:
        yield app, fake, pilot, await open_live(pilot)


async def open_live(pilot):
    """Confirm the session form (remembered values) and wait for the devices."""
    app = pilot.app
    await wait_for_app(pilot, lambda: isinstance(app.screen, SessionScreen))
    await pilot.press("enter")
    await wait_for_app(pilot, lambda: isinstance(app.screen, LiveScreen) and app.ready)
    return app.screen


def screen_text(app) -> str:
    """The screen as the terminal shows it, as plain text."""
    return "\n".join(strip.text for strip in app.screen._compositor.render_strips())


def rendered(widget) -> str:
    """What a widget shows, as plain text."""
    from rich.console import Console

    console = Console(width=200, record=True, file=open("/dev/null", "w"))
    console.print(widget.render())
    return console.export_text()


class StubClassifier:
    """Scores from the image's sum: deterministic, cheap, image-dependent."""

    metadata = {"hash": "stub"}

    def predict(self, image: np.ndarray) -> np.ndarray:
        p = np.full(5, 0.05)
        p[int(image.sum()) % 5] = 0.8
        return p


class FakeClock:
    """A clock the test sets (ns): a replay plays only as the test moves it."""

    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        return self.t


def drill_app(config, sessions: list, **extra):
    """The TUI on real mock-device sessions (a stub classifier), subject S09 with drills on;
    each session it opens is appended to `sessions`."""
    from capture.live.session import Session
    from capture.live.trials import SubjectInfo
    from tui.app import WalkcapApp

    def factory(cfg):
        sessions.append(Session(cfg, classifier=StubClassifier()))
        return sessions[-1]

    return WalkcapApp(
        config,
        session_factory=factory,
        subject=SubjectInfo(subject="S09"),
        ask_subject=False,
        drills=True,
        **extra,
    )
