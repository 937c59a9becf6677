"""The operator's controls, declared once: each is a footer binding *and* a palette command.

Declaring them in one table guarantees that nothing is reachable only by a key the operator
has to remember, or only through the palette (an action kept out of the footer for room, the
trends, is in the palette with its key): the app builds its ``BINDINGS`` and the command
palette provider builds its entries from the same rows (a test checks both).
"""

from __future__ import annotations

from dataclasses import dataclass

from textual.binding import Binding


@dataclass(frozen=True)
class OperatorAction:
    action: str  # the app's action name (action_<name>)
    key: str
    label: str  # short, for the footer
    title: str  # for the command palette
    help: str
    key_display: str | None = None
    # Shown in the footer (at 80 columns two rows hold fourteen keys and no more). Off for a
    # look-back that changes nothing in the cell (the trends): its key works, and the
    # palette lists it with its key.
    footer: bool = True


ACTIONS: tuple[OperatorAction, ...] = (
    OperatorAction("toggle_run", "space", "Run/Pause", "Run / pause",
                   "Pause the scan, or run it again (real time or the chosen speed)",
                   key_display="spc"),
    OperatorAction("step", "s", "Step", "Step one scan",
                   "Run exactly one scan, then stay paused"),
    OperatorAction("step_n", "n", "Step N", "Step N scans…",
                   "Run a chosen number of scans, then stay paused"),
    OperatorAction("speed", "v", "Speed", "Run speed: next (×1, ×10, max)",
                   "Simulated plant only: real time, ten times faster, as fast as possible"),
    OperatorAction("ack", "a", "Ack", "Alarms: acknowledge the selected alarm",
                   "Acknowledge the alarm selected in the alarm list (tab, then ↑↓ to select)"),
    OperatorAction("ack_all", "A", "Ack all", "Alarms: acknowledge all",
                   "Acknowledge every alarm in the list", key_display="A"),
    OperatorAction("explain", "e", "Explain", "Explanation: next level",
                   "Open the next level of the selected alarm's explanation (why, "
                   "consequences, policies); after the last, fold it"),
    OperatorAction("manual", "m", "Manual", "Manual mode: enter / leave…",
                   "Drive the outputs by hand (still filtered); leaving releases them all"),
    OperatorAction("reset", "r", "Reset", "Fault reset…",
                   "Release what is latched (safe state...) after saying what will stay"),
    OperatorAction("policy", "p", "Policy", "Filter policy…",
                   "Switch the safety filter between monitor, block and correct"),
    OperatorAction("inject", "f", "Fault", "SIMULATION: inject a fault…",
                   "Simulated plant only: pick a fault and when it happens"),
    OperatorAction("signals", "g", "Signals", "Chronogram: choose signals…",
                   "Pick the signals the timing diagram draws"),
    OperatorAction("window", "w", "Window", "Chronogram: next time window",
                   "Show the last 5, 10, 30 or 60 seconds"),
    OperatorAction("trends", "t", "Trends", "Trends…",
                   "The history of chosen signals over minutes to days, alarms on the time "
                   "axis (the cell's historian)", footer=False),
    OperatorAction("engineering", "E", "Eng view", "View: engineering names on / off",
                   "Show the model's names too (steps, diagnoser states and labels, flags, "
                   "rules, timers, bounds), or the operator's words only; journalled",
                   key_display="E", footer=False),
    OperatorAction("quit", "q", "Quit", "Quit", "Stop the scan and leave the HMI"),
)


def bindings() -> list[Binding]:
    return [Binding(a.key, a.action, a.label, key_display=a.key_display, tooltip=a.help,
                    show=a.footer) for a in ACTIONS]
