"""The simulated plant, clearly marked SIMULATION: its physical state, the faults the
operator injected (scheduled, active, or over for a fault that lasts a while), and the
damage the simulation recorded.

On a real plant this strip is not shown: there is no hidden truth to display there, and an
operator must never mistake a simulation for the cell.
"""

from __future__ import annotations

from rich.text import Text

from hmi.explain.plain import without_notes
from hmi.link.base import History
from hmi.timefmt import seconds
from hmi.ui.frame import Frame, InjectedFault
from hmi.ui.panel import TextPanel
from hmi.ui.style import MUTED, Level, tag


def plant_text(frame: Frame, recorder: History | None, wide: bool) -> Text:
    snap = frame.snapshot
    text = Text(no_wrap=True, overflow="ellipsis")
    text.append_text(tag("SIMULATION", Level.SIMULATION))
    eng = frame.engineering
    for key, value in snap.plant_state:
        if isinstance(value, bool):
            if value:
                text.append("  ")
                text.append_text(tag(key.upper() if eng else state_words(key).upper(),
                                     Level.ALARM))
        elif key.endswith("position"):
            text.append(f"  {key if eng else state_words(key)} {value:5.1f}%")
        else:
            text.append(f"  {state_value(key, value) if not eng else f'{key} {value}'}",
                        style=MUTED)
    for key, value in snap.plant_counters:
        if key.endswith("cycles"):
            text.append(f"  {key if eng else state_words(key)} {value}", style=MUTED)
    if frame.damage_count:
        text.append("  ")
        text.append_text(tag(f"damage ×{frame.damage_count}", Level.ALARM))
    if frame.injected:
        text.append("  faults:", style=MUTED)
        for fault in frame.injected:
            at = fault.injection.at_us
            duration = fault.injection.duration_us
            name = str(fault.injection.code) if eng else fault_name(fault)
            text.append(" ")
            if duration is not None and at + duration <= snap.time_us:
                # a transient fault (a 2 s halt) is over: said so, not shown as still active
                text.append(f"{name} {seconds(at)}-{seconds(at + duration)} s over",
                            style=MUTED)
            elif at <= snap.time_us:
                until = f" until {seconds(at + duration)} s" if duration is not None else ""
                text.append_text(tag(f"{name} since {seconds(at)} s{until}",
                                     Level.ATTENTION))
            else:
                text.append(f"{name} in {seconds(at - snap.time_us)} s")
    if frame.damage_count and recorder is not None and wide:  # the count, then the faults
        last = [e for e in recorder.recent_events() if e.damage]
        if last:
            text.append(f"  last damage: {last[-1].detail} at {seconds(last[-1].time_us)} s",
                        style=MUTED)
    return text


_UNITS = {"mm": "mm", "pct": "%", "deg": "°", "s": "s"}


def state_words(key: str) -> str:
    """A simulated plant's state key in words: `C1.pallet` -> 'C1 pallet', `elevator_mm`
    -> 'elevator' (its unit goes after the value: :func:`state_value`)."""
    words = key.replace(".", " ").replace("_", " ").split()
    if len(words) > 1 and words[-1] in _UNITS:
        words = words[:-1]
    return " ".join(words)


def state_value(key: str, value: object) -> str:
    """'elevator 784 mm', 'C1 pallet 40.0', 'R1 mode idle'."""
    unit = key.rsplit("_", 1)[-1] if "_" in key else ""
    suffix = f" {_UNITS[unit]}" if unit in _UNITS and unit != "pct" else \
        "%" if unit == "pct" else ""
    return f"{state_words(key)} {value}{suffix}"


def fault_name(fault: InjectedFault) -> str:
    """An injected fault by its description, the device first when the plant names it."""
    text = without_notes(fault.description)
    device = fault.injection.device
    return f"{device}: {text}" if device else text


class SimPanel(TextPanel):
    def __init__(self, recorder: History, *, id: str | None = None):
        super().__init__(id=id)
        self.recorder = recorder

    def show(self, frame: Frame) -> None:
        if self.display != frame.simulated:
            self.display = frame.simulated
        if frame.simulated:
            self.show_text(plant_text(frame, self.recorder, self.app.size.width >= 120))
