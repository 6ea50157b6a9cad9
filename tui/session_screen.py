"""The session form: who walks, under which condition, which trial; validated, remembered.

The last form confirmed and each subject's body data are remembered (tui.remembered) so that
the next session (or a restart after a crash) opens with them, with the operator; another
subject never inherits them, and notes are never kept. The trial is the next free number for
the subject and condition in the recordings folder. Notes that look like they name a person,
a date of birth or a place are warned of under the field.
"""

from __future__ import annotations

import logging

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Grid, Horizontal, Vertical
from textual.screen import Screen
from textual.suggester import SuggestFromList
from textual.widgets import Button, Checkbox, Footer, Input, Label, Select, Static

from capture.errors import CaptureError
from capture.live.trials import SubjectInfo
from capture.recording.personal import NOTES_HELP, note_warnings
from tui.remembered import (  # noqa: F401  (the form's memory, named here too)
    Remembered,
    last_session_path,
    load_last_session,
    load_remembered,
    save_last_session,
)
from tui.subject import SUBJECT_FIELDS

log = logging.getLogger(__name__)

_ID_CHARS = r"[A-Za-z0-9_-]*"
# Form field -> (label, kind); kind decides the widget and how the text converts.
FIELDS = {
    "subject": ("Subject id", "id"),
    "condition": ("Condition", "id"),
    "trial": ("Trial", "int"),
    "height_m": ("Height (m)", "float"),
    "weight_kg": ("Weight (kg)", "float"),
    "age": ("Age (years)", "int"),
    "sex": ("Sex", ("", "female", "male", "other")),
    "amputee": ("Amputee", "bool"),
    "side": ("Side", ("", "left", "right")),
    "residual_limb_cm": ("Residual limb (cm)", "float"),
    "notes": ("Notes", "text"),
}


def info_from_form(values: dict[str, object], pattern: str | None = None) -> SubjectInfo:
    """Form values (text, or bool for the checkbox) -> a validated SubjectInfo.

    Raises CaptureError naming the field when a value is not a number or out of range, or
    when the subject id does not fit `pattern` ([session] subject_pattern).
    """
    kwargs: dict[str, object] = {}
    for name, (label, kind) in FIELDS.items():
        raw = values.get(name, "")
        if kind == "bool":
            kwargs[name] = bool(raw)
            continue
        text = str(raw if raw is not None else "").strip()
        if kind in ("int", "float"):
            if not text:
                if name == "trial":
                    raise CaptureError("trial: a number from 1")
                kwargs[name] = None
                continue
            try:
                kwargs[name] = int(text) if kind == "int" else float(text)
            except ValueError:
                raise CaptureError(
                    f"{label.split(' (')[0].lower()}: {text!r} is not a number"
                ) from None
        else:
            kwargs[name] = text
    info = SubjectInfo(**kwargs)
    info.validate(pattern)
    return info


def form_values(info: SubjectInfo) -> dict[str, object]:
    """SubjectInfo -> what each form widget shows."""
    values: dict[str, object] = {}
    for name, (_, kind) in FIELDS.items():
        v = getattr(info, name)
        values[name] = (
            v
            if kind == "bool"
            else ("" if v is None else (f"{v:g}" if isinstance(v, float) else str(v)))
        )
    return values


class YesNoBox(Checkbox):
    """A checkbox whose state reads without colour: a tick and "yes", or blank and "no"."""

    @property
    def BUTTON_INNER(self) -> str:  # noqa: N802  (Textual's name for the glyph)
        return "✔" if self.value else " "

    def watch_value(self) -> None:
        super().watch_value()
        self.label = "yes" if self.value else "no"


class SessionScreen(Screen[SubjectInfo | None]):
    """Dismisses with the confirmed SubjectInfo, or None when cancelled (escape)."""

    BINDINGS = [
        Binding("ctrl+s", "confirm", "Start", priority=True),
        Binding("escape", "cancel", "Back"),
        Binding("ctrl+r", "retry", "Retry devices", priority=True),
        Binding("ctrl+q", "app.quit", "Quit", priority=True),
    ]

    def __init__(self, info: SubjectInfo, *, can_cancel: bool = False) -> None:
        super().__init__()
        self.info = info
        self.can_cancel = can_cancel
        self.operator = ""
        # what the form filled in for which subject and condition: a field still showing
        # it is the operator's to replace when the subject or condition changes
        self._filled = form_values(info)
        self._filled_for = (info.subject, info.condition)

    def compose(self) -> ComposeResult:
        values = form_values(self.info)
        with Vertical(id="session-form"):
            yield Static("[b]walkcap[/b] — session", id="form-title")
            with Grid(id="form-grid"):
                for name, (label, kind) in FIELDS.items():
                    yield Label(label, classes="form-label")
                    yield self._field(name, kind, values[name])
                yield Label("Operator", classes="form-label")
                yield Input(
                    value=self._operator(),
                    id="f-operator",
                    compact=True,
                    max_length=64,
                    select_on_focus=False,
                )
            yield Static(NOTES_HELP, id="notes-help")
            yield Static(self._notes_warning(values["notes"]), id="notes-warning")
            yield Static("", id="form-error")
            yield Static("", id="device-status")
            with Horizontal(id="form-buttons"):
                yield Button("Start session (enter)", variant="primary", id="confirm", compact=True)
                if self.can_cancel:
                    yield Button("Back (escape)", id="cancel", compact=True)
        yield Footer()

    @staticmethod
    def _field(name: str, kind, value):
        if isinstance(kind, tuple):
            options = [(v or "—", v) for v in kind]
            return Select(options, value=value, allow_blank=False, id=f"f-{name}", compact=True)
        if kind == "bool":
            return YesNoBox(
                "yes" if value else "no", value=bool(value), id=f"f-{name}", compact=True
            )
        # a remembered value is kept: typing goes on from its end, it does not replace it
        common = dict(value=str(value), id=f"f-{name}", compact=True, select_on_focus=False)
        if kind == "id":
            suggester = SuggestFromList(["indoor", "outdoor"]) if name == "condition" else None
            return Input(restrict=_ID_CHARS, max_length=32, suggester=suggester, **common)
        if kind == "int":
            return Input(type="integer", **common)
        if kind == "float":
            return Input(type="number", **common)
        return Input(max_length=500, **common)

    @staticmethod
    def _notes_warning(text: str) -> str:
        """One line when the notes look like they hold a name, a date of birth or a place
        (capture.recording.personal.note_warnings)."""
        found = note_warnings(text)
        if not found:
            return ""
        return (
            f"[b yellow]Notes look like they hold {' and '.join(found)}: "
            "they go into every recording; keep people out of them[/]"
        )

    def _operator(self) -> str:
        return self.app.config.session.operator

    def on_mount(self) -> None:
        self.watch(self.app, "status", self._show_status)
        self.query_one("#f-subject", Input).focus()

    def _show_status(self, status: str) -> None:
        self.query_one("#device-status", Static).update(status)

    def values(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for name in FIELDS:
            widget = self.query_one(f"#f-{name}")
            out[name] = widget.value
        return out

    def action_confirm(self) -> None:
        try:
            info = info_from_form(self.values(), self.app.config.session.subject_pattern)
        except CaptureError as e:
            self.query_one("#form-error", Static).update(f"[b red]{e}[/]")
            return
        self.operator = str(self.query_one("#f-operator", Input).value).strip()
        save_last_session(info, operator=self.operator, days=self.app.config.session.remember_days)
        self.app.config.session.operator = self.operator  # written into every recording
        self.dismiss(info)

    def action_retry(self) -> None:
        self.app.retry()

    def check_action(self, action: str, parameters: tuple) -> bool | None:
        return self.can_cancel if action == "cancel" else True

    def action_cancel(self) -> None:
        if self.can_cancel:
            self.dismiss(None)

    def on_input_changed(self, event: Input.Changed) -> None:
        """Another subject or condition: that subject's own fields (empty for a new one) and
        its next free trial, in every field the operator has not typed into. Notes that look
        personal: a warning under them."""
        if event.input.id == "f-notes":
            warning = self._notes_warning(str(event.value))
            self.query_one("#notes-warning", Static).update(warning)
            return
        if event.input.id not in ("f-subject", "f-condition"):
            return
        values = self.values()
        key = (str(values["subject"]).strip(), str(values["condition"]).strip())
        if key == self._filled_for or not all(key):
            return
        folder = self.app.config.session.recordings
        days = self.app.config.session.remember_days
        fresh = form_values(load_remembered(days=days).form_for(*key, folder))
        for name in (*SUBJECT_FIELDS, "trial"):
            widget = self.query_one(f"#f-{name}")
            if widget.value == self._filled[name]:
                widget.value = fresh[name]
                self._filled[name] = fresh[name]
        self._filled_for = key

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.action_confirm()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        event.stop()
        if event.button.id == "confirm":
            self.action_confirm()
        else:
            self.action_cancel()
