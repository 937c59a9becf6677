"""The alarm list (ISA-18.2): what needs the operator, unacknowledged first.

One row per alarm, in the engine's order (unacknowledged — active or cleared — first, then by
priority, newest first)::

    ▲ UNACK          P2  3.000 s  Conveyor C1 …: cannot end within its acceptable time  LATCHED
    ● ACK            P3  7.920 s  Valve V1: close order blocked — never hold …  ×4
    ○ CLEARED-UNACK  P3  6.000 s  Valve V1: open order blocked — …

The state is a symbol *and* a word; the colour of the state and of the priority follows the
priority (P1 red, P2 and P3 amber) and only active alarms carry it: a cleared alarm waiting
for its acknowledgement is grey. ``×4`` counts the returns of a chattering alarm collapsed
into one row; ``LATCHED`` marks an active alarm that stays until a fault reset.

The list is a panel of its own with a height it sets itself (one row per alarm, up to a cap
that depends on the terminal's height), placed outside the body so the chronogram gives up
rows for it: at 80×24 it is never pushed off the screen. When there are more alarms than
rows, the rows scroll around the selection and the border says how many are out of view.

The selection (↑↓ when the list has the focus, or a click) says which alarm the explanation
panel explains and which one ``a`` acknowledges; enter or a click also opens its
explanation. The list posts :class:`AlarmSelected` up when it changes; it never sends a
command itself.
"""

from __future__ import annotations

from typing import Any

from rich.style import Style
from rich.text import Text
from textual import events
from textual.binding import Binding
from textual.message import Message

from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK, CLEARED_UNACK, Alarm
from hmi.timefmt import seconds
from hmi.ui.frame import Frame
from hmi.ui.panel import TextPanel, set_title
from hmi.ui.style import MUTED, OK_SYMBOL, STYLE, Level

STATES = {
    ACTIVE_UNACK: ("▲", "UNACK"),
    ACTIVE_ACK: ("●", "ACK"),
    CLEARED_UNACK: ("○", "CLEARED-UNACK"),
}
STATE_WIDTH = max(len(f"{s} {w}") for s, w in STATES.values())
PRIORITY_LEVEL = {1: Level.ALARM, 2: Level.ATTENTION, 3: Level.ATTENTION}
SELECTED = Style(bgcolor="#4a4a4a")
WIDE = 110  # from this width on, a device column
DEVICE_W = 16  # the device column's widest (a longer name is cut)


SHORT = 30  # below this height: three rows, and a top border only (see app.tcss)


def rows_for_height(height: int) -> int:
    """How many alarm rows the list may take on a terminal this tall."""
    if height < SHORT:
        return 3
    if height < 40:
        return 4
    return 6


def urgent_count(alarms: tuple[Alarm, ...]) -> int:
    """How many alarms lead the list as the most urgent: active, unacknowledged, and of the
    highest priority among those (the list is sorted so that they come first)."""
    if not alarms or alarms[0].state != ACTIVE_UNACK:
        return 0
    best = alarms[0].priority
    count = 0
    for alarm in alarms:
        if alarm.state != ACTIVE_UNACK or alarm.priority != best:
            break
        count += 1
    return count


def rows_shown(count: int, urgent: int, selected: int, rows: int, top: int
               ) -> tuple[list[int], int]:
    """The indices of the alarms on screen, and the first index of the scrolled part.

    The `urgent` first alarms are pinned at the top (all of them when the selection is one
    of them, else all but the one row the selection needs); the other rows scroll over the
    rest so that the selection stays in view."""
    if count <= rows:
        return list(range(count)), 0
    pinned = min(urgent, rows if selected < min(urgent, rows) else rows - 1)
    window = rows - pinned
    if selected >= pinned:
        if selected < top:
            top = selected
        elif selected >= top + window:
            top = selected - window + 1
    top = max(pinned, min(top, count - window))
    return [*range(pinned), *range(top, top + window)], top


def state_cell(alarm: Alarm) -> Text:
    symbol, word = STATES.get(alarm.state, ("?", alarm.state))
    cell = f"{symbol} {word}".ljust(STATE_WIDTH)
    if alarm.state == CLEARED_UNACK:
        return Text(cell, style=MUTED)
    style = STYLE[PRIORITY_LEVEL.get(alarm.priority, Level.ATTENTION)]
    if alarm.state == ACTIVE_ACK:
        style = style + Style(bold=False)
    return Text(cell, style=style)


def without_device(text: str, device: str) -> str:
    """The level-1 line without its leading device name, when a column already shows it
    ("Valve V1: close order blocked" -> "close order blocked")."""
    if device and text.startswith(device) and text[len(device):len(device) + 1] in (":", " "):
        return text[len(device) + 1:].lstrip()
    return text


DETAIL_LINES = 2  # the selected alarm's full first line, wrapped: at most this many lines


def detail_lines(text: str, width: int) -> list[str]:
    """The selected alarm's whole level-1 sentence, wrapped at word boundaries on at most
    DETAIL_LINES lines of `width` cells (the last cut with an ellipsis only if it must)."""
    words, lines, line = text.split(), [], ""
    for word in words:
        candidate = f"{line} {word}" if line else word
        if len(candidate) <= width or not line:
            line = candidate
        else:
            lines.append(line)
            line = word
    if line:
        lines.append(line)
    if len(lines) > DETAIL_LINES:
        last = " ".join(lines[DETAIL_LINES - 1:])
        lines = [*lines[:DETAIL_LINES - 1], last[:width - 1] + "…"]
    return [x[:width] for x in lines]


def alarm_row(alarm: Alarm, width: int, device_w: int = 0, time_w: int = 7) -> Text:
    """One alarm as one line of at most `width` cells (the text ends in an ellipsis)."""
    return fitted_row(alarm, width, device_w, time_w)[0]


def fitted_row(alarm: Alarm, width: int, device_w: int = 0, time_w: int = 7
               ) -> tuple[Text, bool]:
    """The row, and whether its text had to be cut to fit."""
    row = Text(no_wrap=True, overflow="ellipsis", end="")
    row.append_text(state_cell(alarm))
    muted = alarm.state == CLEARED_UNACK
    plain = MUTED if muted else Style()
    # Every gap ends the run before it (`P1 ` then `10.830 s  `): a viewer that drops the
    # spaces opening a run (librsvg, some browsers) still shows `P1 10.830 s`, not `P110.830`.
    row.append("  ")
    # the priority in its colour too (P1 red, P2-P3 amber; grey once cleared): docs/ui.md
    raised = seconds(alarm.raised_us)
    row.append(f"P{alarm.priority} " + " " * max(0, time_w - len(raised)),
               style=MUTED if muted else
               STYLE[PRIORITY_LEVEL.get(alarm.priority, Level.ATTENTION)])
    row.append(f"{raised} s  ", style=MUTED)
    text = alarm.text
    if device_w:
        row.append(alarm.device[:device_w].ljust(device_w) + " ", style=plain)
        text = without_device(text, alarm.device)
    tail = Text(end="")
    if alarm.explanation is not None and alarm.explanation.ambiguous:
        tail.append("  ").append("? ambiguous", style=STYLE[Level.ATTENTION])
    if alarm.chattering or alarm.returns:
        tail.append("  ").append(f"×{alarm.returns + 1}", style=Style(bold=True)
                                 if alarm.chattering else MUTED)
        if alarm.chattering:
            tail.append(" ").append("chattering", style=MUTED)
    if alarm.latched and alarm.active:  # cleared: the latch that held it is gone
        tail.append("  ").append("LATCHED", style=Style(bold=True))
    if alarm.comment:
        tail.append("  ").append("✎", style=MUTED)
    room = width - row.cell_len - tail.cell_len
    cut = room < len(text)
    if cut:
        text = text[:max(0, room - 1)] + "…" if room > 0 else ""
    row.append(text, style=plain)
    row.append_text(tail)
    return row, cut


class AlarmSelected(Message):
    """The operator selected an alarm (None: the list is empty); `open`: and asked for its
    explanation (enter, or a click)."""

    def __init__(self, key: str | None, open: bool = False) -> None:
        super().__init__()
        self.key = key
        self.open = open


class AlarmList(TextPanel):
    """Alarms, unacknowledged first; a selection for the explanation and for ``a``."""

    can_focus = True
    BINDINGS = [
        Binding("up", "move(-1)", "Previous alarm", show=False),
        Binding("down", "move(1)", "Next alarm", show=False),
        Binding("home", "move(-1000)", show=False),
        Binding("end", "move(1000)", show=False),
        Binding("enter", "open", "Explain this alarm", show=False),
    ]

    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.alarms: tuple[Alarm, ...] = ()
        self.selected: str | None = None  # the selected alarm's key
        self.shelved = 0  # alarms shelved (not listed): said on the border
        self.top = 0  # index of the first row of the scrolled part
        # the keys of the alarms on screen, top to bottom: what a click on a row means (keys,
        # not indices: the list may have changed, or emptied, since it was drawn)
        self._on_screen: tuple[str, ...] = ()
        self._rows: tuple[int, bool] | None = None  # lines drawn and compact border, as set
        self._alarm_rows = 0  # of those lines, the alarm rows (then the selected one's line)
        self._drawn: tuple[Any, ...] | None = None

    def on_mount(self) -> None:
        self.border_title = "Alarms"

    # -- display -----------------------------------------------------------------------------
    def show(self, frame: Frame) -> None:
        alarms = frame.cell.alarms
        shelved = len(frame.cell.shelved)
        changed = alarms != self.alarms or shelved != self.shelved
        self.alarms = alarms
        self.shelved = shelved
        keys = [a.key for a in alarms]
        if self.selected not in keys:
            self._select(keys[0] if keys else None)
        if changed or self._drawn is None:
            self._draw()

    def on_resize(self) -> None:
        self._draw()

    def on_focus(self) -> None:
        self._draw()

    def on_blur(self) -> None:
        self._draw()

    @property
    def selected_alarm(self) -> Alarm | None:
        return next((a for a in self.alarms if a.key == self.selected), None)

    def _draw(self) -> None:
        height = self.app.size.height
        rows = min(max(len(self.alarms), 1), rows_for_height(height))
        urgent = urgent_count(self.alarms)
        if rows <= urgent < len(self.alarms) and self._index() >= urgent:
            rows += 1  # the urgent rows pinned, and the selection's row under them
        width = max(20, self.content_size.width or self.app.size.width - 4)
        # The selected alarm's whole first sentence on its own line(s) when its row cuts it
        # (80 columns): the device and the plain fault are always readable.
        detail: list[str] = []
        selected = self.selected_alarm
        if selected is not None:
            _, cut = fitted_row(selected, width - 2, 0, max(len(seconds(a.raised_us))
                                                            for a in self.alarms))
            if cut and width < WIDE:
                detail = detail_lines(selected.text, width - 4)
        self._alarm_rows = rows
        lines = rows + len(detail)
        compact = height < SHORT
        if (lines, compact) != self._rows:
            self._rows = (lines, compact)  # (a resize may change the border alone)
            # the border: top and bottom lines; on a short screen, the top line only
            self.set_class(compact, "-compact")
            self.styles.height = lines + (1 if compact else 2)
        key = (self.alarms, self.selected, rows, width, self.has_focus, tuple(detail))
        if key == self._drawn:
            return
        self._drawn = key
        unack = sum(a.state != ACTIVE_ACK for a in self.alarms)
        title = (f"Alarms · {unack} unacknowledged / {len(self.alarms)}"
                 if self.alarms else "Alarms")
        if self.shelved:
            title += f" · {self.shelved} shelved"
        if not self.alarms:
            self._on_screen = ()
            set_title(self, title)
            self.show_text(Text(f"{OK_SYMBOL} no alarm", style=MUTED))
            return
        shown, self.top = rows_shown(len(self.alarms), urgent, self._index(), rows, self.top)
        self._on_screen = tuple(self.alarms[k].key for k in shown)
        pinned = min(urgent, len(shown))
        above = shown[-1] + 1 - len(shown)  # out of view between the pinned and the rest
        below = len(self.alarms) - shown[-1] - 1
        hidden = []
        if urgent > pinned:
            hidden.append(f"✗ {urgent - pinned} more P{self.alarms[0].priority} unack"
                          if self.alarms[0].priority == 1 else
                          f"▲ {urgent - pinned} more P{self.alarms[0].priority} unack")
        if above:
            hidden.append(f"↑ {above} more")
        if below > 0:
            hidden.append(f"↓ {below} more")
        set_title(self, " · ".join((title, *hidden)))  # on the top line: always shown
        device_w = 0
        if width >= WIDE:
            device_w = min(DEVICE_W, max(len(a.device) for a in self.alarms))
        time_w = max(len(seconds(a.raised_us)) for a in self.alarms)
        text = Text(no_wrap=True, overflow="ellipsis")
        for i, alarm in enumerate(self.alarms[k] for k in shown):
            if i:
                text.append("\n")
            row = alarm_row(alarm, width - 2, device_w, time_w)
            mine = alarm.key == self.selected
            text.append("› " if mine else "  ", style=Style(bold=True))
            text.append_text(row)
            if mine and self.has_focus:
                text.stylize(SELECTED, len(text) - row.cell_len - 2, len(text))
        for k, line in enumerate(detail):
            text.append("\n")
            text.append("  ↳ " if k == 0 else "    ", style=MUTED)
            text.append(line, style=Style(bold=True) if selected and selected.active
                        else MUTED)
        self.show_text(text)

    def _index(self) -> int:
        keys = [a.key for a in self.alarms]
        return keys.index(self.selected) if self.selected in keys else 0

    # -- selection ---------------------------------------------------------------------------
    def _select(self, key: str | None, open: bool = False) -> None:
        if key != self.selected or open:
            self.selected = key
            self.post_message(AlarmSelected(key, open))

    def action_open(self) -> None:
        """Enter: explain the selected alarm (again, if another situation was picked)."""
        if self.selected is not None:
            self._select(self.selected, open=True)

    def select(self, key: str) -> bool:
        """Select an alarm by key (from the palette, a constraint clicked); False if none."""
        if not any(a.key == key for a in self.alarms):
            return False
        self._select(key)
        self._draw()
        return True

    def action_move(self, step: int) -> None:
        if not self.alarms:
            return
        index = max(0, min(len(self.alarms) - 1, self._index() + step))
        self._select(self.alarms[index].key)
        self._draw()

    def on_click(self, event: events.Click) -> None:
        offset = event.get_content_offset(self)
        if offset is None:
            return
        row = offset.y
        if 0 <= row < min(self._alarm_rows, len(self._on_screen)):
            key = self._on_screen[row]
            if any(a.key == key for a in self.alarms):
                self._select(key, open=True)
                self._draw()
