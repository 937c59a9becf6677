"""The fault reset and recovery dialogs' lines, as the operator reads them.

What a reset would do is read from the snapshot by hmi.explain.reset (the runtime checks it
again when the confirmation arrives); here it is styled: will be reset, or stays and why, and
when the cell moved while the dialog was open, what changed since (marked).
"""

from __future__ import annotations

from dataclasses import dataclass

from rich.text import Text

from hmi.explain.plain import PlainNames
from hmi.explain.reset import ResetLine, changes, reset_preview
from hmi.project.model import Project, RecoveryProcedure
from hmi.session.view import CellView
from hmi.timefmt import seconds
from hmi.ui.style import MUTED, OK_SYMBOL, Level, tag


def recovery_lines(project: Project, spec: RecoveryProcedure,
                   engineering: bool = False) -> list[str]:
    """What starting a recovery procedure does, for its confirmation dialog: the orders by
    their descriptions ("the close order"), their names in the engineering view."""
    plain = PlainNames(project)
    steps = "; ".join(f"{k}. {step.description}" for k, step in enumerate(spec.steps, 1))
    others = [v.name for v in project.outputs if v.name not in spec.outputs]
    relaxed = [c for c in project.constraints if c.name in spec.relaxes]

    def orders(names: list[str]) -> str:
        return ", ".join(names if engineering else (f"the {plain.name(n)}" for n in names))

    held = len(others) > 1
    lines = [f"{spec.device or project.name}: {steps} (it stops by itself at the end, or "
             f"after {seconds(spec.timeout_us)} s with every output safe).",
             f"Only {orders(list(spec.outputs))} {'act' if len(spec.outputs) > 1 else 'acts'}"
             + (f"; {orders(others)} held at {'their safe values' if held else 'its safe value'}"
                if others else "")
             + "; the control program waits."]
    rules = [c.description or c.name for c in spec.constraints]
    if rules:
        lines.append("Still filtered, by its own rules: " + "; ".join(rules) + ".")
    if relaxed:
        lines.append("Not enforced meanwhile: " + "; ".join(
            (c.description or c.name)[:1].lower() + (c.description or c.name)[1:]
            for c in relaxed) + ".")
    lines.append("Only after the repair: a device still jammed would be driven against its "
                 "jam until the time limit.")
    lines.append("Then: r (fault reset), and m to leave recovery: the program restarts from "
                 "its initial steps.")
    return lines


@dataclass(frozen=True)
class Asked:
    """A fault reset dialog the operator confirmed after the cell had moved: what it showed,
    as of which scan. The dialog asked again starts with what changed since."""

    shown: tuple[ResetLine, ...]
    scan: int
    time_us: int


def reset_line(line: ResetLine, engineering: bool = False) -> Text:
    """One line of the fault reset dialog: will be reset, or stays and why; in the
    engineering view, the model's names after the plain words."""
    if line.resets:
        text = Text(f"{OK_SYMBOL} will be reset: {line.what}")
    else:
        text = tag("stays", Level.ATTENTION)
        text.append(f": {line.what}")
        if line.why:
            text.append(f" — {line.why}")
    if line.note:
        text.append(f" ({line.note})", style=MUTED)
    if engineering and line.detail:
        text.append(f" [{line.detail}]", style=MUTED)
    return text


def reset_lines(cell: CellView, asked: Asked | None = None,
                engineering: bool = False) -> list[Text | str]:
    """The fault reset dialog's lines: what a reset would release and what stays, as of
    `cell`. Asked again (`asked`), first that nothing was done and what no longer holds, then
    the lines, those that changed since marked."""
    snap = cell.snapshot
    now = reset_preview(snap, cell.alarms)
    lines: list[Text | str] = []
    fresh: set[tuple[str, bool, str, str]] = set()
    if asked is not None:
        gone, new = changes(list(asked.shown), now)
        fresh = {line.promise for line in new}
        head = tag("CHANGED", Level.ATTENTION)
        head.append(f" The cell moved since you read this (scan {asked.scan}, t = "
                    f"{seconds(asked.time_us)} s): nothing was done.")
        lines.append(head)
        lines += [Text("  no longer: ", style=MUTED) + reset_line(line, engineering)
                  for line in gone]
        if not asked.shown:
            lines.append(Text("  no longer: nothing latched, the reset changing nothing",
                              style=MUTED))
        lines.append(Text("What the reset would do now" + (" (► changed):" if fresh else ":"),
                          style="bold"))
    for line in now:
        shown = reset_line(line, engineering)
        lines.append(Text("► ", style="bold") + shown if line.promise in fresh
                     else Text("  ") + shown if asked is not None else shown)
    if not now:
        lines.append(Text("Nothing is latched: the reset will change nothing.", style=MUTED))
    lines.append(Text(f"(as of scan {snap.scan}, t = {seconds(snap.time_us)} s; the cell "
                      "keeps running while this dialog is open)", style=MUTED))
    return lines
