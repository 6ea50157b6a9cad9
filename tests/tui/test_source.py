"""The screens' Source protocol is what every source has: the live session, the replay
source and the UI tests' fake each implement all of it, and only a replay is a Playback."""

from __future__ import annotations

import pytest

from capture.config import Config
from capture.live.session import Session
from tests.tui_fake_session import FakeSession
from tui.replay import ReplaySource
from tui.source import Playback, Source


def members(protocol: type) -> set[str]:
    names = set(protocol.__annotations__)
    names |= {n for n in vars(protocol) if not n.startswith("_")}
    return names


@pytest.mark.parametrize(
    "make",
    [lambda: Session(Config()), lambda: ReplaySource("trial.mcap"), FakeSession],
    ids=["session", "replay", "fake"],
)
def test_every_source_has_the_whole_protocol(make):
    source = make()
    missing = [name for name in sorted(members(Source)) if not hasattr(source, name)]
    assert not missing
    assert isinstance(source, Playback) == isinstance(source, ReplaySource)


def test_the_protocol_names_what_the_screens_use():
    assert {"trial_notice", "trial", "alarms", "inject", "start_recording"} <= members(Source)
    assert {"path", "corrections", "saved_path", "unsaved", "save_corrections"} <= members(Playback)
