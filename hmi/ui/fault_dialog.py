"""SIMULATION: pick a fault of the simulated plant and when it happens (now, or in N s).

Fault injection exists for training and commissioning: watching the filter and the diagnosers
react to a stuck sensor or a jammed valve. The dialog is marked SIMULATION in reverse video
and returns an :class:`~hmi.project.injection.Injection` in the engine's virtual time; the app sends
it as an ``InjectFault`` command.
"""

from __future__ import annotations

from collections.abc import Callable

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.widgets import Input, Label, OptionList, Static
from textual.widgets.option_list import Option

from hmi.explain.plain import without_notes
from hmi.project.injection import Injection
from hmi.timefmt import parse_duration
from hmi.ui.dialogs import Dialog
from hmi.ui.style import Level, banner


def parse_delay(text: str) -> int:
    """'' or 'now' or '0' -> 0; '5' -> 5 s; '500ms', '2.5s' -> as written (microseconds)."""
    text = text.strip().lower()
    if text in ("", "now", "0"):
        return 0
    try:
        return round(float(text) * 1_000_000)
    except ValueError:
        return parse_duration(text)


def fault_words(device: str, description: str, several: bool) -> str:
    """A fault as the operator view names it: its description (the device first when the
    plant has several), not the simulation's code (`valve.F13`: the engineering view's)."""
    text = without_notes(description)
    return f"{device}: {text}" if several else text[:1].upper() + text[1:]


class FaultDialog(Dialog[Injection | None]):
    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, faults: list[tuple[str, str, str]], now_us: Callable[[], int],
                 single_device: bool, engineering: bool = False):
        """`now_us` reads the engine's time: a delay counts from the confirmation, not from
        when the dialog opened (the cell keeps running while it is open)."""
        super().__init__(id="fault-dialog")
        self.faults = faults
        self.now_us = now_us
        self.single_device = single_device
        self.engineering = engineering

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog dialog-wide"):
            yield Static(banner("SIMULATION — inject a fault into the simulated plant",
                                Level.SIMULATION), classes="dialog-title", markup=False)
            # First, so that it is on screen at 80x24 when the dialog opens; and true: the
            # first enter chooses the fault and moves to its time, the second injects it.
            yield Label("↑↓ fault · enter: choose · enter again: inject · esc: cancel",
                        classes="dialog-hint")
            yield OptionList(*(Option(f"{device}.{code}  {description}" if self.engineering
                                      else fault_words(device, description,
                                                       not self.single_device),
                                      id=f"{device}.{code}")
                               for device, code, description in self.faults), id="faults")
            yield Static("When: in how many seconds (0 or empty = at the next scan)",
                         classes="dialog-line")
            yield Input("0", id="delay", placeholder="0, 5, 2.5s, 500ms", compact=True)
            yield Static("For how long (empty = until repaired; a halt that ends: 2s)",
                         classes="dialog-line")
            yield Input("", id="duration", placeholder="until repaired; or 2s, 500ms", compact=True)
            yield Label("", id="error", classes="dialog-error")

    def on_mount(self) -> None:
        faults = self.query_one("#faults", OptionList)
        if self.faults:
            faults.highlighted = 0
        faults.focus()

    def _inject(self) -> None:
        faults = self.query_one("#faults", OptionList)
        if faults.highlighted is None:
            self.query_one("#error", Label).update("✗ choose a fault")
            return
        option = faults.get_option_at_index(faults.highlighted)
        device, _, code = (option.id or "").partition(".")
        try:
            delay = parse_delay(self.query_one("#delay", Input).value)
        except ValueError:
            self.query_one("#error", Label).update(
                "✗ the delay is a number of seconds or a duration such as 500ms")
            return
        if delay < 0:
            self.query_one("#error", Label).update("✗ the delay cannot be negative")
            return
        duration_text = self.query_one("#duration", Input).value.strip()
        try:
            duration = parse_delay(duration_text) if duration_text else None
        except ValueError:
            self.query_one("#error", Label).update(
                "✗ the duration is a number of seconds or a duration such as 500ms")
            return
        if duration is not None and duration <= 0:
            self.query_one("#error", Label).update(
                "✗ the duration must be longer than zero (empty: until repaired)")
            return
        self.dismiss(Injection(code, self.now_us() + delay,
                               None if self.single_device else device, duration))

    @on(OptionList.OptionSelected)
    def _fault_chosen(self, event: OptionList.OptionSelected) -> None:
        self.query_one("#delay", Input).focus()

    @on(Input.Submitted)
    def _submitted(self) -> None:
        self._inject()

    @on(OptionList.OptionHighlighted)
    def _fault_highlighted(self, event: OptionList.OptionHighlighted) -> None:
        self.query_one("#error", Label).update("")

    def action_cancel(self) -> None:
        self.dismiss(None)
