"""Choose the chronogram's signals: a checklist of every Boolean signal of the project."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Label, SelectionList, Static
from textual.widgets.selection_list import Selection

from hmi.ui.recorder import FOV_SUFFIX, Signal
from hmi.ui.style import Level, banner

KIND_WORDS = {"input": "input", "output": "output (written)", "fov": "output FOV",
              "timer": "timer Q", "observer": "observer", "memory": "memory",
              "step": "GRAFCET step"}


class SignalDialog(ModalScreen[tuple[str, ...] | None]):
    BINDINGS = [Binding("escape", "cancel", "Cancel"),
                Binding("enter", "done", "Done", priority=True)]

    def __init__(self, signals: tuple[Signal, ...], chosen: tuple[str, ...],
                 descriptions: dict[str, str]):
        super().__init__(id="signal-dialog")
        self.signals = signals
        self.chosen = chosen
        self.descriptions = descriptions

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield Static(banner("Chronogram signals", Level.NORMAL), classes="dialog-title")
            selections = []
            for s in self.signals:
                base = s.name[: -len(FOV_SUFFIX)] if s.kind == "fov" else s.name
                desc = self.descriptions.get(base, "")
                selections.append(Selection(f"{s.name:<10} {KIND_WORDS[s.kind]:<17} {desc}",
                                            s.name, s.name in self.chosen))
            yield SelectionList[str](*selections, id="signals")
            yield Label("space: tick / untick    enter: done    esc: cancel",
                        classes="dialog-hint")

    def on_mount(self) -> None:
        self.query_one(SelectionList).focus()

    def action_done(self) -> None:
        picked = set(self.query_one(SelectionList).selected)
        self.dismiss(tuple(s.name for s in self.signals if s.name in picked))

    def action_cancel(self) -> None:
        self.dismiss(None)
