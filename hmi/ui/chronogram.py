"""A timing diagram of chosen Boolean signals over the last N seconds (000, Fig. 4).

Engineers read timing better than tables: which order came first, how long the valve took
to reach its end switch, whether a sensor glitched. One row per signal, drawn with block
characters, the time axis underneath in virtual seconds:

    O     1 ▁▁▁▁▐█████▌▁▁▁▁▁▁▁
    fso   0 ▁▁▁▁▁▁▁▁▐███████▌▁
              12s       14s

Each column covers window/width of time. A column where the signal stayed put is drawn
high (``█``) or low (``▁``); one change in it is a rising (``▐``) or falling (``▌``) edge;
several changes (a pulse shorter than a column) are ``▒``, so a one-scan glitch is never
lost however wide the window. A blank column is before the first recorded scan.
"""

from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widget import Widget

from hmi.link.base import History
from hmi.session.recorder import FOV_SUFFIX, Trace
from hmi.ui.containment import ContainedPump
from hmi.ui.frame import Frame
from hmi.ui.style import MUTED, STYLE, Level

HIGH, LOW, RISE, FALL, MULTI, UNKNOWN = "█", "▁", "▐", "▌", "▒", " "
WINDOWS_US = (5_000_000, 10_000_000, 30_000_000, 60_000_000)
TICK_STEPS_US = (100_000, 200_000, 500_000, 1_000_000, 2_000_000, 5_000_000, 10_000_000,
                 20_000_000, 30_000_000, 60_000_000)
MAX_LABEL = 8


def columns(trace: Trace, start_us: int, window_us: int, width: int,
            end_us: int | None = None) -> str:
    """The glyphs of one signal over `width` columns covering (start, start + window].

    Column c covers (start + c·window//width, start + (c+1)·window//width]. Columns after
    `end_us` (the last scan: the future, while the run is younger than the window) are
    blank. The work is proportional to the changes in the window, not to the width: runs of
    columns without a change are drawn in one piece.
    """
    def column_of(t: int) -> int:  # the column whose span holds time t (t > start)
        return max(0, -(-(t - start_us) * width // window_us) - 1)

    def level(value: bool | None) -> str:
        return UNKNOWN if value is None else (HIGH if value else LOW)

    limit = width
    if end_us is not None:
        elapsed = end_us - start_us
        limit = min(width, max(0, -(-elapsed * width // window_us)))
    out: list[str] = []
    changes = trace.changes
    value = trace.initial
    filled = 0
    i, n = 0, len(changes)
    while i < n:
        c = column_of(changes[i][0])
        if c >= limit:
            break
        out.append(level(value) * (c - filled))
        before, count = value, 0
        while i < n and column_of(changes[i][0]) == c:
            value = changes[i][1]
            count += 1
            i += 1
        if count > 1:
            out.append(MULTI)
        elif before is None:  # the first sample ever: no edge to show
            out.append(level(value))
        else:
            out.append(RISE if value else FALL)
        filled = c + 1
    out.append(level(value) * (limit - filled))
    out.append(UNKNOWN * (width - limit))
    return "".join(out)


def tick_step(window_us: int, width: int, min_gap: int = 8) -> int:
    for step in TICK_STEPS_US:
        if step * width // window_us >= min_gap:
            return step
    return TICK_STEPS_US[-1]


def time_label(t_us: int, step_us: int) -> str:
    if step_us % 1_000_000 == 0:
        return f"{t_us // 1_000_000}s"
    return f"{t_us / 1_000_000:.1f}s"


def axis(start_us: int, window_us: int, width: int) -> str:
    """The time axis: labels at round virtual times, left-aligned on their column."""
    step = tick_step(window_us, width)
    row = [" "] * width
    t = (start_us // step + 1) * step
    free_from = 0
    while t <= start_us + window_us:
        col = (t - start_us) * width // window_us - 1
        label = "┊" + time_label(t, step)
        if col >= free_from and col + len(label) <= width:
            row[col:col + len(label)] = label
            free_from = col + len(label) + 1
        t += step
    return "".join(row)


class Chronogram(ContainedPump, Widget):
    """Draws the recorder's history of the chosen signals up to the frame's scan time."""

    signals: reactive[tuple[str, ...]] = reactive(tuple)
    window_us: reactive[int] = reactive(WINDOWS_US[1])

    def __init__(self, recorder: History, signals: tuple[str, ...], *,
                 engineering: tuple[str, ...] = (), id: str | None = None):
        """`engineering`: signals drawn after the chosen ones in the engineering view only
        (the timers: TON1 is the model's name, not a signal of the machine)."""
        super().__init__(id=id)
        self.recorder = recorder
        self.frame: Frame | None = None
        self._drawn: tuple[Any, ...] | None = None
        self.engineering = engineering
        self.set_reactive(Chronogram.signals, signals)

    @property
    def drawn(self) -> tuple[str, ...]:
        """The signals drawn: the chosen ones, and in the engineering view the timers."""
        if self.frame is None or not self.frame.engineering:
            return self.signals
        return self.signals + tuple(n for n in self.engineering if n not in self.signals)

    def show(self, frame: Frame) -> None:
        """Redraw only when something visible moved: a new edge, or time crossing a column
        (one column is window/width: ~90 ms for 10 s on 110 columns, 0.5 s for 60 s)."""
        self.frame = frame
        width = max(1, self.content_size.width)
        key = (frame.snapshot.time_us * width // self.window_us, self.recorder.change_count,
               tuple(sorted(frame.changed)), frame.engineering)
        if key != self._drawn:
            self._drawn = key
            self.refresh()
        # the mark before a value, said where it shows
        legend = "≠: the filter changed it" if any(
            name in frame.changed for name in self.drawn) else ""
        if self.border_subtitle != legend:
            self.border_subtitle = legend

    def watch_window_us(self) -> None:
        self.border_title = f"Chronogram · last {self.window_us // 1_000_000} s"

    def on_mount(self) -> None:
        self.watch_window_us()

    def render(self) -> Text:
        """Drawn by Textual's compositor, outside any handler: an error here is contained
        here (the chronogram says so; the rest of the screen is drawn)."""
        try:
            return self._draw_text()
        except Exception as exc:
            fault = self.app.contain("Chronogram drawing", exc)  # type: ignore[attr-defined]
            return Text(f"✗ chronogram not drawn: {fault.error}", style=MUTED)

    def _draw_text(self) -> Text:
        text = Text(no_wrap=True, overflow="crop")
        signals = self.drawn
        if not signals:
            text.append("no signals chosen: press g to choose", style=MUTED)
            return text
        frame = self.frame
        width = self.size.width
        # whole names (PLATE_CLOSED, not PLATE_CL) while 40 columns of plot are left
        cap = 2 * MAX_LABEL if width - 2 * MAX_LABEL - 3 >= 40 else MAX_LABEL
        label_w = min(cap, max(len(_label(n)) for n in signals))
        plot_w = max(1, width - label_w - 3)
        end = frame.snapshot.time_us if frame else 0
        start = max(0, end - self.window_us)
        outputs_changed = frame.changed if frame else {}
        rows = max(1, (self.content_size.height or len(signals) + 1) - 1)
        shown = signals if len(signals) <= rows else signals[: rows - 1]
        spaced = 2 * len(shown) <= rows  # room to spare: a blank line between signals
        for name in shown:
            value_now = self._now(name)
            changed = name in outputs_changed
            label = _label(name)[:label_w].ljust(label_w)
            style = STYLE[Level.ATTENTION] if changed else MUTED
            text.append(label, style=style)
            text.append("≠" if changed else " ", style=style)
            text.append("?" if value_now is None else ("1" if value_now else "0"))
            text.append(" ")
            trace = self.recorder.trace(name, start, end)
            text.append(columns(trace, start, self.window_us, plot_w, end))
            text.append("\n\n" if spaced else "\n")
        if len(shown) < len(signals):
            text.append(f"+{len(signals) - len(shown)} more signals: "
                        "g to choose, or a taller terminal\n", style=MUTED)
        text.append(" " * (label_w + 3), style=MUTED)
        text.append(axis(start, self.window_us, plot_w), style=MUTED)
        return text

    def _now(self, name: str) -> bool | None:
        frame = self.frame
        if frame is None:
            return None
        snap = frame.snapshot
        if name.endswith(FOV_SUFFIX):
            out = name[: -len(FOV_SUFFIX)]
            return snap.fov_map.get(out)
        slot = snap.layout.slots.get(name)
        return None if slot is None else bool(snap.values[slot])


def _label(name: str) -> str:
    if name.endswith(FOV_SUFFIX):
        return name[: -len(FOV_SUFFIX)] + " fov"
    return name
