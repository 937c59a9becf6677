"""Modal dialogs for the actions that deserve a second thought or a parameter.

Confirmation is asked for what changes how the cell is protected or driven (manual mode,
filter policy, fault reset); a dialog says what will happen in plain words before the
operator agrees. Each dialog returns its answer through ``dismiss`` and never sends a
command itself: the app does, so every action still goes through ``Session.command``.

Keys typed before a dialog is on screen are not its keys: an Enter meant for the alarm list
must not confirm a fault reset whose dialog opened a moment late. Every dialog notes when it
was first painted (:attr:`Dialog.shown_at`); the app drops the keys that were typed before
(``PlcHmiApp.on_event``). A confirmation needs ``y`` (or a click on its button): Enter only
moves the focus between its buttons, and the focus starts on Cancel.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from rich.text import Text
from textual import events, on
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.css.scalar import Unit
from textual.screen import ModalScreen, Screen
from textual.widgets import Button, Input, Label, OptionList, Static
from textual.widgets.option_list import Option

from hmi.engine.commands import CommandResult
from hmi.ui.containment import ContainedPump
from hmi.ui.style import Level, banner
from hmi.ui.textual_adapter import event_clock

_R = TypeVar("_R")


def _title(text: str, level: Level) -> Static:
    title = banner(text, level) if level is not Level.NORMAL else Text(f" {text} ",
                                                                      style="bold")
    return Static(title, classes="dialog-title", markup=False)


def top_rows(main: Screen[Any]) -> int:
    """How many lines the status bar and the banners take at the top of the main screen,
    from what they hold now rather than from the last layout: a banner that appears while a
    dialog is open (manual mode taking effect, a safe-state latch) is drawn with the frame
    that shows it, before its region is laid out, and the dialog must already be below it."""
    rows = 0
    width = main.size.width
    for widget in main.query("#status, #banners"):
        if not widget.display:
            continue
        styles = widget.styles
        height = styles.height
        if height is not None and height.unit is Unit.CELLS:
            lines = int(height.value)
        else:
            gutter = styles.gutter
            lines = widget.get_content_height(main.size, main.size,
                                              max(0, width - gutter.width)) + gutter.height
            limit = styles.max_height
            if limit is not None and limit.unit is Unit.CELLS:
                lines = min(lines, int(limit.value))
        rows += lines
    return rows


def keep_clear(app: App[Any]) -> None:
    """Keep the status bar and the banners of the main screen in view above every dialog
    (and the command palette): the dialog's box starts below them, so nothing the cell says
    about itself (SAFE STATE, MANUAL, a disconnected plant) is covered while the operator
    reads or types. Called when a dialog mounts and with every frame, since a banner may
    come or go while the dialog is open. (The box moves, not the screen: a padded screen
    shifts the cell drawn under it down by as much.)"""
    stack = app.screen_stack
    if len(stack) < 2:
        return
    clear = top_rows(stack[0])
    if not clear:  # not composed yet
        return
    for screen in stack[1:]:
        # (in a real terminal Textual gives each screen its toast rack and tooltip first:
        # the box is the first child of the screen's own)
        box = next((c for c in screen.children if not c.has_class("-textual-system")), None)
        if not isinstance(screen, ModalScreen) or box is None:
            continue
        base = box.__dict__.setdefault("_clear_base", box.styles.margin.top)  # palette: 3
        top = max(base, clear)
        margin = box.styles.margin
        if margin.top != top:
            box.styles.margin = (top, margin.right, margin.bottom, margin.left)
        if isinstance(screen, Dialog):  # the whole box below the banners
            room = max(5, app.size.height - top - 1)
            if box.styles.max_height is None or box.styles.max_height.value != room:
                box.styles.max_height = room


class Dialog(ContainedPump, ModalScreen[_R]):
    """A modal dialog of the HMI: its errors contained, and the moment it was first shown
    known, so that keys typed before it was on screen are dropped (see the module)."""

    shown_at: float | None = None  # Textual's event clock (Message.time) when first painted

    def on_mount(self) -> None:
        self.call_after_refresh(self._painted)
        keep_clear(self.app)

    def _painted(self) -> None:
        if self.shown_at is None:
            self.shown_at = event_clock()

    def takes(self, event: events.Key) -> bool:
        """Whether a key is the dialog's: typed once the dialog was on screen."""
        return self.shown_at is not None and event.time >= self.shown_at


class ConfirmDialog(Dialog[bool]):
    """Yes / no, with the consequences listed. y confirms; n or escape cancels; enter only
    moves the focus between the buttons (it never confirms)."""

    BINDINGS = [
        Binding("y", "answer(True)", "Confirm"),
        Binding("n", "answer(False)", "Cancel"),
        Binding("escape", "answer(False)", "Cancel", show=False),
        Binding("enter", "app.focus_next", "Next button", show=False, priority=True),
        Binding("g", "alternative", "Alternative", show=False),
    ]
    AUTO_FOCUS = "#no"

    def __init__(self, title: str, lines: Sequence[Text | str], confirm: str = "Confirm",
                 level: Level = Level.ATTENTION, dialog_id: str = "confirm",
                 alternative: str | None = None):
        super().__init__(id=dialog_id)
        self.title_text = title
        self.lines = list(lines)
        self.confirm_label = confirm
        self.level = level
        # A third answer (key g): "Start recovery" in the fault reset dialog, when the reset
        # cannot do what the operator wants and a recovery can. Dismisses with the string
        # "alternative".
        self.alternative = alternative

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield _title(self.title_text, self.level)
            hint = "y: confirm    n / esc: cancel"
            if self.alternative:
                hint = f"y: confirm    g: {self.alternative.lower()}    n / esc: cancel"
            yield Label(hint, classes="dialog-hint")
            for line in self.lines:
                yield Static(line, classes="dialog-line", markup=False)
            with Horizontal(classes="dialog-buttons"):
                yield Button(f"{self.confirm_label} (y)", id="yes", variant="default")
                if self.alternative:
                    yield Button(f"{self.alternative} (g)", id="alternative",
                                 variant="default")
                yield Button("Cancel (n)", id="no", variant="default")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)

    def action_alternative(self) -> None:
        if self.alternative:
            self.dismiss("alternative")  # type: ignore[arg-type]

    @on(Button.Pressed)
    def _pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "alternative":
            self.dismiss("alternative")  # type: ignore[arg-type]
            return
        self.dismiss(event.button.id == "yes")


class InfoDialog(Dialog[None]):
    """Lines to read (the OPC UA server's page); escape, enter or q closes it."""

    BINDINGS = [Binding("escape", "close", "Close"), Binding("enter", "close", "Close",
                                                           show=False),
                Binding("q", "close", "Close", show=False)]

    def __init__(self, title: str, lines: Sequence[Text | str], *, dialog_id: str = "info"):
        super().__init__(id=dialog_id)
        self.title_text = title
        self.lines = list(lines)

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield _title(self.title_text, Level.NORMAL)
            for line in self.lines:
                yield Static(line, classes="dialog-line", markup=False)
            yield Label("esc / enter: close", classes="dialog-hint")

    def action_close(self) -> None:
        self.dismiss(None)


class TextDialog(Dialog[str | None]):
    """One line of text (an operator's comment on an alarm); enter keeps it, escape drops."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, title: str, prompt: str, *, dialog_id: str = "text-dialog",
                 max_length: int = 500):
        super().__init__(id=dialog_id)
        self.title_text = title
        self.prompt = prompt
        self.max_length = max_length

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield _title(self.title_text, Level.NORMAL)
            yield Label("enter: keep    esc: cancel", classes="dialog-hint")
            yield Static(self.prompt, classes="dialog-line", markup=False)
            yield Input("", id="text", max_length=self.max_length, compact=True)
            yield Label("", id="error", classes="dialog-error")

    def on_mount(self) -> None:
        super().on_mount()
        self.query_one("#text", Input).focus()

    @on(Input.Submitted)
    def _submitted(self, event: Input.Submitted) -> None:
        if not event.value.strip():
            self.query_one("#error", Label).update("✗ write something, or esc to cancel")
            return
        self.dismiss(event.value.strip())

    def action_cancel(self) -> None:
        self.dismiss(None)


class ReasonDialog(Dialog[tuple[str, str] | None]):
    """Why: asked before the commands whose reason goes to the journal with the person's
    name (the filter policy, forcing, manual mode, recovery, shelving; EU GMP Annex 11
    §9); with `password`, the person's password again too (switching the filter to
    monitor). Enter on the reason moves to the password, enter there sends; escape
    cancels: nothing is sent. Dismisses with (reason, password) — the password "" when
    not asked — and the app sends them with the command (the runtime checks them)."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, what: str, password: bool = False, *, max_length: int = 500):
        super().__init__(id="reason-dialog")
        self.what = what
        self.password = password
        self.max_length = max_length

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield _title(f"Why: {self.what}?", Level.ATTENTION)
            yield Label("enter: " + ("next" if self.password else "send") + "    esc: cancel",
                        classes="dialog-hint")
            yield Static("The reason goes to the journal with your name.",
                         classes="dialog-line", markup=False)
            yield Input("", id="reason", placeholder="reason", max_length=self.max_length,
                        compact=True)
            if self.password:
                yield Static("Your password again (this lets unsafe orders through):",
                             classes="dialog-line", markup=False)
                yield Input("", id="password", placeholder="password", password=True,
                            max_length=1024, compact=True)
            yield Label("", id="error", classes="dialog-error")

    def on_mount(self) -> None:
        super().on_mount()
        self.query_one("#reason", Input).focus()

    @on(Input.Submitted)
    def _submitted(self, event: Input.Submitted) -> None:
        reason = self.query_one("#reason", Input).value.strip()
        if not reason:
            self.query_one("#error", Label).update("✗ write why, or esc to cancel")
            self.query_one("#reason", Input).focus()
            return
        if not self.password:
            self.dismiss((reason, ""))
            return
        password = self.query_one("#password", Input)
        if event.input.id == "reason" or not password.value:
            password.focus()
            return
        self.dismiss((reason, password.value))

    def action_cancel(self) -> None:
        self.dismiss(None)


class LockScreen(Dialog[None]):
    """The screen left untouched for the users file's idle-lock: covered, the status bar
    and the banners still in view above it (the cell runs on), until its person types
    their password again — checked by the runtime (`unlock`: its answer). Escape does not
    leave it; ctrl+q still ends the screen."""

    BINDINGS = [Binding("escape", "stay", "Stay locked", show=False)]

    def __init__(self, who: str, idle: str, unlock: Callable[[str], CommandResult]):
        super().__init__(id="lock-screen")
        self.who = who
        self.idle = idle
        self.unlock = unlock

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield _title("LOCKED: sign in again", Level.ATTENTION)
            yield Static(f"Nobody touched this screen for {self.idle}: it locked. The cell "
                         "runs on; nothing can be sent from here until you sign in.",
                         classes="dialog-line", markup=False)
            yield Static(f"Signed in as {self.who}. Your password:", classes="dialog-line",
                         markup=False)
            yield Input("", id="password", placeholder="password", password=True,
                        max_length=1024, compact=True)
            yield Label("", id="error", classes="dialog-error")
            yield Label("enter: unlock    ctrl+q: leave this screen", classes="dialog-hint")

    def on_mount(self) -> None:
        super().on_mount()
        self.query_one("#password", Input).focus()

    @on(Input.Submitted)
    def _submitted(self, event: Input.Submitted) -> None:
        field = self.query_one("#password", Input)
        result = self.unlock(event.value)
        field.value = ""
        if result.accepted:
            self.dismiss(None)
        else:
            self.query_one("#error", Label).update(f"✗ {result.message}")

    def action_stay(self) -> None:
        """(escape: the lock stays)"""


class StepDialog(Dialog[int | None]):
    """How many scans to step (1 to MAX_STEPS)."""

    MAX_STEPS = 10_000
    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, default: int = 10):
        super().__init__(id="step-dialog")
        self.default = default

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield _title("Step N scans", Level.NORMAL)
            yield Static(f"Number of scans to run, then pause (1 to {self.MAX_STEPS}):",
                         classes="dialog-line")
            yield Input(str(self.default), type="integer", id="count",
                        select_on_focus=True, compact=True)
            yield Label("", id="error", classes="dialog-error")
            yield Label("enter: step    esc: cancel", classes="dialog-hint")

    @on(Input.Submitted)
    def _submitted(self, event: Input.Submitted) -> None:
        try:
            count = int(event.value)
        except ValueError:
            count = 0
        if not 1 <= count <= self.MAX_STEPS:
            self.query_one("#error", Label).update(
                f"✗ enter a whole number from 1 to {self.MAX_STEPS}")
            return
        self.dismiss(count)

    def action_cancel(self) -> None:
        self.dismiss(None)


class StoppingOptionList(OptionList):
    """An option list whose cursor stops at the first and last option: ↓ on the last one
    does not jump back to the top (a short list read as a loop, the choice lost)."""

    def action_cursor_down(self) -> None:
        if self.highlighted is None or self.highlighted < self.option_count - 1:
            super().action_cursor_down()

    def action_cursor_up(self) -> None:
        if self.highlighted is None or self.highlighted > 0:
            super().action_cursor_up()


class ChoiceDialog(Dialog[str | None]):
    """Pick one of a few options (filter policy, speed...); enter picks, escape cancels."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, title: str, options: Sequence[tuple[str, Text | str]],
                 current: str | None = None, level: Level = Level.NORMAL,
                 dialog_id: str = "choice", note: str = ""):
        super().__init__(id=dialog_id)
        self.title_text = title
        self.options = list(options)
        self.current = current
        self.level = level
        self.note = note

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield _title(self.title_text, self.level)
            if self.note:
                yield Static(self.note, classes="dialog-line", markup=False)
            yield StoppingOptionList(*(Option(prompt, id=key) for key, prompt in self.options),
                                     id="choices")
            yield Label("↑↓ choose    enter: select    esc: cancel", classes="dialog-hint")

    def on_mount(self) -> None:
        options = self.query_one("#choices", OptionList)
        keys = [key for key, _ in self.options]
        if self.current in keys:
            options.highlighted = keys.index(self.current)
        options.focus()

    @on(OptionList.OptionSelected)
    def _selected(self, event: OptionList.OptionSelected) -> None:
        self.dismiss(event.option.id)

    def action_cancel(self) -> None:
        self.dismiss(None)
