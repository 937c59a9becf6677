"""The screen among the cell's screens: who is in control, and whether the runtime is there.

- **Control.** Where several screens are attached, or this one is not in control, the status
  bar says who is (`● in control` for this screen, `▲ control: bob (terminal)`, `▲ nobody in
  control`); alone and in control (the usual case) it says nothing more.
- **The runtime lost.** When the runtime goes away (its connection closed: killed, crashed,
  stopped), nothing on the screen is live any more: a red banner says so at once, with when
  and why, the panels are dimmed, the status bar says RUNTIME LOST, and every command is
  refused. A runtime that says nothing for a while (a tick comes every second) is shown NOT
  RESPONDING the same way until it speaks again. The values shown then are the last ones
  received, never presented as live.
"""

from __future__ import annotations

from rich.text import Text

from hmi.timefmt import seconds
from hmi.ui.frame import Frame
from hmi.ui.style import MUTED, Level, banner, tag

SILENT_S = 3.0  # no word from the runtime for this long: not responding


def lost_fields(frame: Frame) -> list[tuple[Text, int]]:
    """The status bar of a screen whose runtime is gone: that first, then only what was
    last known, said as such (never the run state, as if it were live)."""
    snap = frame.snapshot
    mode = {"auto": "AUTO", "manual": "MANUAL"}.get(snap.mode, snap.mode.upper())
    return [(tag("RUNTIME LOST", Level.ALARM), 0), (Text(frame.project, style="bold"), 2),
            (Text(f"last known: {mode}, filter {snap.policy}, scan {snap.scan} at "
                  f"{seconds(snap.time_us)} s", style=MUTED), 0)]


def control_field(frame: Frame) -> tuple[Text, int] | None:
    """The status bar's word on control (None: alone and in control, or no runtime)."""
    control = frame.control
    if control is None or frame.lost:
        return None
    holder = control.holder
    mine = holder is not None and holder.id == frame.me
    if mine and len(control.clients) == 1:
        return None
    if mine:
        asked = control.asked_by
        text = Text("● in control")
        if asked is not None:
            text = tag(f"{asked.identity.user} ({asked.id}) asks for control",
                       Level.ATTENTION)
        return text, 0
    if holder is None:
        return tag("nobody in control", Level.ATTENTION), 0
    who = holder.identity
    return tag(f"control: {who.user} ({who.door}, {holder.id})", Level.ATTENTION), 0


def lost_field(frame: Frame) -> tuple[Text, int] | None:
    if frame.lost:
        return tag("RUNTIME LOST", Level.ALARM), 0
    if frame.silent_s >= SILENT_S:
        return tag("RUNTIME NOT RESPONDING", Level.ALARM), 0
    return None


def lost_banner(frame: Frame) -> Text | None:
    """The red banner of a runtime gone or silent: nothing shown is live."""
    if frame.lost:
        line = banner("RUNTIME LOST", Level.ALARM)
        line.append(f" {frame.lost} · nothing shown is live (greyed: as of scan "
                    f"{frame.snapshot.scan}) · no command is sent · q: quit")
        return line
    if frame.silent_s >= SILENT_S:
        line = banner("RUNTIME NOT RESPONDING", Level.ALARM)
        line.append(f" no word from the runtime for {frame.silent_s:.0f} s · the values "
                    f"shown (scan {frame.snapshot.scan}) may be stale")
        return line
    return None
