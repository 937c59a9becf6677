"""Choose the chronogram's signals: a checklist of every Boolean signal of the project.

Textual's SelectionList marks a ticked row by colour only; here a ticked row reads ``[✓]``
and an unticked one ``[ ]``, so the list reads on a monochrome terminal too.
"""

from __future__ import annotations

from typing import Generic, Protocol, TypeVar

from rich.text import Text
from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.widgets import Label, OptionList, Static
from textual.widgets.option_list import Option

from hmi.session.recorder import FOV_SUFFIX
from hmi.ui.dialogs import Dialog
from hmi.ui.style import Level, banner

KIND_WORDS = {"input": "input", "output": "output (written)", "fov": "output FOV",
              "timer": "timer Q", "observer": "observer", "memory": "memory",
              "step": "GRAFCET step"}


class _Named(Protocol):
    """What the list needs of a signal: its name and kind (the chronogram's signals,
    hmi.session.recorder.Signal; the history's, hmi.history.catalogue.Signal)."""

    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> str: ...


SignalT = TypeVar("SignalT", bound=_Named)


class SignalDialog(Dialog[tuple[str, ...] | None], Generic[SignalT]):
    TITLE_TEXT = "Chronogram signals"
    BINDINGS = [
        Binding("escape", "cancel", "Cancel"),
        Binding("space", "tick", "Tick / untick", priority=True),
        Binding("enter", "done", "Done", priority=True),
    ]

    def __init__(self, signals: tuple[SignalT, ...], chosen: tuple[str, ...],
                 descriptions: dict[str, str]):
        super().__init__(id="signal-dialog")
        self.signals = signals
        self.chosen = set(chosen)
        self.descriptions = descriptions

    def _prompt(self, signal: SignalT) -> Text:
        base = signal.name[: -len(FOV_SUFFIX)] if signal.kind == "fov" else signal.name
        desc = self.descriptions.get(base, "")
        if desc == base:
            desc = ""
        mark = "[✓]" if signal.name in self.chosen else "[ ]"
        return Text(f"{mark} {signal.name:<8} {KIND_WORDS[signal.kind]:<17} {desc}",
                    no_wrap=True, overflow="ellipsis")

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield Static(banner(self.TITLE_TEXT, Level.NORMAL), classes="dialog-title")
            yield OptionList(*(Option(self._prompt(s), id=s.name) for s in self.signals),
                             id="signals")
            yield Label("space: tick / untick    enter: done    esc: cancel",
                        classes="dialog-hint")

    def on_mount(self) -> None:
        options = self.query_one(OptionList)
        options.highlighted = 0
        options.focus()

    def action_tick(self) -> None:
        options = self.query_one(OptionList)
        index = options.highlighted
        if index is None:
            return
        signal = self.signals[index]
        self.chosen ^= {signal.name}
        options.replace_option_prompt_at_index(index, self._prompt(signal))

    @on(OptionList.OptionSelected)
    def _clicked(self, event: OptionList.OptionSelected) -> None:
        self.action_tick()

    def action_done(self) -> None:
        self.dismiss(tuple(s.name for s in self.signals if s.name in self.chosen))

    def action_cancel(self) -> None:
        self.dismiss(None)
