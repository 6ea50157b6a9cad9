"""The Textual application (placeholder screen until the [tui] issue lands)."""
from __future__ import annotations

from textual.app import App, ComposeResult
from textual.widgets import Footer, Header, Static

from capture.config import Config


class WalkcapApp(App):
    TITLE = "walkcap"
    BINDINGS = [("q", "quit", "Quit")]

    def __init__(self, config: Config | None = None) -> None:
        super().__init__()
        self.config = config or Config()

    def compose(self) -> ComposeResult:
        c = self.config
        yield Header()
        yield Static(
            f"walkcap: camera [b]{c.camera.backend}[/b] at {c.camera.fps:g} fps, "
            f"IMU [b]{c.imu.backend}[/b] at {c.imu.rate_hz} Hz, "
            f"model {c.model.path or 'bundled'}.\n\n"
            "The live session screen lands with the [tui] issue. Press q to quit.",
            id="placeholder",
        )
        yield Footer()
