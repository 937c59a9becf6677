"""The trend screen: chosen signals over minutes to days, read from the cell's history.

Opened with ``t`` (or the palette: ``Trends…``, ``Trends: maintenance of Valve V1``), over
the main screen whose status bar and banners stay in view above it (a new alarm is never
hidden behind a trend). Keys: ← → the cursor (its values beside the names, its events under
the axis), ⇧← ⇧→ (or [ ]) half a window earlier or later, + - zoom (1 min to 7 days, the
cursor's instant kept in place), end back to now (following the cell), home the whole
history, g the signals, escape back.

The history is read in a worker thread, never in the UI's: the screen keeps the last picture
(and says "reading…") until the new one is there, and a query that a newer one superseded
is dropped. It reads through its own read-only connection to where the cell's history is
kept (the link's facts: the runtime records, any screen reads), so a slow database slows
the trend, never the scan nor the rest of the HMI. What it draws: hmi.ui.trend.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from datetime import tzinfo
from typing import TYPE_CHECKING, NamedTuple

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.widget import Widget
from textual.widgets import Static

from hmi.history.catalogue import Signal
from hmi.history.query import HistoryReader, Window
from hmi.history.store import StoreError
from hmi.ui.containment import ContainedPump
from hmi.ui.dialogs import Dialog
from hmi.ui.footer import HmiFooter
from hmi.ui.signal_dialog import SignalDialog
from hmi.ui.style import MUTED, Level, tag
from hmi.ui.trend import (
    ZOOMS_US,
    column_end,
    draw,
    plot_width,
    window_title,
    zoom_text,
)

if TYPE_CHECKING:
    from hmi.ui.palette import PaletteEntry

DEFAULT_ZOOM_US = ZOOMS_US[2]  # 15 min
FOLLOW_EVERY_US = 1_000_000  # following now: read again at most once a second of the cell


class TrendChart(ContainedPump, Widget):
    """The last picture read (or why there is none)."""

    def __init__(self, zone: tzinfo | None, *, id: str | None = None):
        super().__init__(id=id)
        self.zone = zone
        self.window: Window | None = None
        self.cursor = 0
        self.message: Text | None = Text("reading the history…", style=MUTED)

    def render(self) -> Text:
        try:
            if self.window is None:
                return self.message or Text("")
            text = draw(self.window, self.cursor, self.content_size.height, self.zone)
            if self.message is not None:
                text.append("\n")
                text.append_text(self.message)
            return text
        except Exception as exc:
            fault = self.app.contain("Trend drawing", exc)  # type: ignore[attr-defined]
            return Text(f"✗ trend not drawn: {fault.error}", style=MUTED)


class _Picture(NamedTuple):
    """What a picture shows: its signals, its window and its width in columns."""

    names: tuple[str, ...]
    start_us: int
    end_us: int
    width: int


# A picture read: the window, the signals the history holds and its extent; or why not.
_Read = tuple[Window, list[Signal], tuple[int, int] | None] | str


class TrendSignalDialog(SignalDialog[Signal]):
    """The trend's signals: every signal the history holds, with its kind and meaning."""

    TITLE_TEXT = "Trend signals"

    def _prompt(self, signal: Signal) -> Text:
        mark = "[✓]" if signal.name in self.chosen else "[ ]"
        kind = {"bool": "on/off", "number": signal.unit or "number", "enum": "state",
                "counter": "count"}.get(signal.kind, signal.kind)
        return Text(f"{mark} {signal.name:<14} {kind:<7} {signal.description}",
                    no_wrap=True, overflow="ellipsis")


class TrendScreen(Dialog[None]):
    BINDINGS = [
        Binding("escape", "close", "Back"),
        Binding("left", "cursor(-1)", "Cursor", key_display="←"),
        Binding("right", "cursor(1)", "Cursor", key_display="→"),
        Binding("shift+left,left_square_bracket", "pan(-1)", "Earlier", key_display="⇧←"),
        Binding("shift+right,right_square_bracket", "pan(1)", "Later", key_display="⇧→"),
        Binding("plus,equals_sign", "zoom(-1)", "Zoom in", key_display="+"),
        Binding("minus", "zoom(1)", "Zoom out", key_display="-"),
        Binding("end", "now", "Now"),
        Binding("home", "whole", "All"),
        Binding("g", "signals", "Signals"),
    ]

    def __init__(self, history: str, cell: str, signals: Sequence[str], now_us: int,
                 zoom_us: int = DEFAULT_ZOOM_US, zone: tzinfo | None = None,
                 whole: bool = False):
        """`history`: where the cell's history is (hmi.history.target.parse_target); `now_us`:
        the cell's newest scan, on the history's time axis."""
        super().__init__(id="trend-screen")
        self.history = history
        self.cell = cell
        self.signals: list[str] = list(signals)
        self.zone = zone
        self.span_us = zoom_us
        self.now_us = now_us
        self.end_us = now_us
        self.following = True
        self.cursor: int | None = None  # None: the last column
        self.known: list[Signal] = []  # what the history holds (read with each picture)
        self.extent: tuple[int, int] | None = None  # the history's first and last instant
        self._reader: HistoryReader | None = None
        self._reader_lock = threading.Lock()
        self._wanted: _Picture | None = None
        self._whole = whole
        self.reads = 0  # pictures read (tests, the bench)
        self._shown: _Picture | None = None  # the key of the picture on the screen

    # -- layout -----------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        with Vertical(id="trend-box"):
            yield Static(id="trend-header")
            yield TrendChart(self.zone, id="trend-chart")
        yield HmiFooter(compact=True)

    def on_mount(self) -> None:
        super().on_mount()
        self._header()
        self.call_after_refresh(self.request)

    def on_resize(self) -> None:
        self.call_after_refresh(self.request)

    @property
    def chart(self) -> TrendChart:
        return self.query_one(TrendChart)

    def _width(self) -> int:
        return plot_width(self.chart.content_size.width or self.app.size.width)

    def _header(self, reading: bool = False) -> None:
        start = self.end_us - self.span_us
        line = Text(" TRENDS ", style="bold reverse")
        line.append(f" {self.cell} · {zoom_text(self.span_us)} · "
                    f"{window_title(start, self.end_us, self.following, self.zone)}")
        if reading:
            line.append("  reading…", style=MUTED)
        self.query_one("#trend-header", Static).update(line)

    # -- reading, in a worker thread ----------------------------------------------------------
    def _key(self) -> _Picture:
        return _Picture(tuple(self.signals), self.end_us - self.span_us, self.end_us,
                        self._width())

    @property
    def up_to_date(self) -> bool:
        """The picture on the screen is the one it should show now: its signals, window and
        width (a picture read before the screen was laid out, or for the signals chosen
        before, is not; tests and the bench wait on this, not on a count of reads)."""
        return self.is_attached and self._shown is not None and self._shown == self._key()

    def request(self) -> None:
        """Read the picture the screen should show now, unless it is the one shown (or
        being read)."""
        if not self.is_attached:
            return
        key = self._key()
        if key == self._wanted:
            return
        self._wanted = key
        self._header(reading=True)
        self.run_worker(lambda: self._read(key), thread=True, exclusive=True, group="trend",
                        exit_on_error=False, name="trend")

    def _open(self) -> HistoryReader:
        with self._reader_lock:
            if self._reader is None:
                from hmi.history.target import open_store, parse_target
                self._reader = HistoryReader(open_store(parse_target(self.history),
                                                        read_only=True), self.cell)
            return self._reader

    def _read(self, key: _Picture) -> None:
        """In a worker thread: the picture of `key`, handed to the UI thread."""
        names, start, end, width = key
        try:
            reader = self._open()
            known = reader.signals()
            extent = reader.span()
            names = tuple(n for n in names if reader.signal(n) is not None)
            window = reader.window(names, start, end, width)
            result: _Read = (window, known, extent)
        except StoreError as exc:
            result = str(exc)
        except Exception as exc:  # a bug: contained in the UI thread, said on the screen
            result = f"{type(exc).__name__}: {exc}"
            self.app.call_from_thread(self.app.contain,  # type: ignore[attr-defined]
                                      "reading the history", exc)
        self.app.call_from_thread(self._arrived, key, result)

    def _arrived(self, key: _Picture, result: _Read) -> None:
        if key != self._wanted or not self.is_attached:
            return  # a newer picture was asked for meanwhile
        self.reads += 1
        self._shown = key
        chart = self.chart
        if isinstance(result, str):
            chart.message = tag("no history", Level.ATTENTION) + Text(f": {result}")
            chart.window = None
        else:
            window, self.known, self.extent = result
            chart.window = window
            chart.message = None
            if self._whole:
                self._whole = False
                self.call_later(self.action_whole)
            missing = [n for n in self.signals if n not in {s.name for s in self.known}]
            if missing:
                chart.message = Text(f"not in this history: {', '.join(missing)}", style=MUTED)
            elif not window.drawn:
                chart.message = Text("no signal chosen: g to choose", style=MUTED)
        chart.cursor = self._cursor_column()
        self._header()
        chart.refresh()

    def _cursor_column(self) -> int:
        """The cursor's column; on now (None), the newest column the history covers: the
        last second or so is not written yet, and the values read there would all be "?"."""
        width = self._width()
        if self.cursor is not None:
            return max(0, min(width - 1, self.cursor))
        window = self.chart.window
        if window is not None and window.drawn:
            for c in range(min(width, window.width) - 1, -1, -1):
                if any(c < len(d.columns) and d.columns[c].known for d in window.drawn):
                    return c
        return width - 1

    # -- the cell goes on -----------------------------------------------------------------------
    def tick(self, now_us: int) -> None:
        """The cell's newest scan (the app's refresh): following, the window moves with it,
        read again once it has moved by a column, at most once a second of the cell."""
        self.now_us = now_us
        if not self.following:
            return
        step = max(FOLLOW_EVERY_US, self.span_us // max(1, self._width()))
        if now_us - self.end_us >= step or now_us < self.end_us:
            self.end_us = now_us
            self.request()

    # -- actions -------------------------------------------------------------------------------
    def action_close(self) -> None:
        self.dismiss(None)

    def action_cursor(self, step: int) -> None:
        width = self._width()
        column = self._cursor_column() + step
        if column < 0 or column >= width:
            self.action_pan(-1 if column < 0 else 1)
            column = max(0, min(width - 1, column))
        self.cursor = None if column == width - 1 and self.following else column
        self.chart.cursor = self._cursor_column()
        self.chart.refresh()

    def _place(self, end_us: int) -> None:
        """The window ends at `end_us`, or follows the cell when that is now or later."""
        self.following = end_us >= self.now_us
        self.end_us = self.now_us if self.following else end_us
        self.request()

    def action_pan(self, direction: int) -> None:
        self._place(self.end_us + direction * self.span_us // 2)

    def action_zoom(self, direction: int) -> None:
        index = min(range(len(ZOOMS_US)), key=lambda k: abs(ZOOMS_US[k] - self.span_us))
        index = max(0, min(len(ZOOMS_US) - 1, index + direction))
        span = ZOOMS_US[index]
        if span == self.span_us:
            return
        if self.following and self.cursor is None:  # on now: it stays on now, following
            self.span_us = span
            self._place(self.now_us)
            return
        width = self._width()
        window = self.chart.window
        column = self._cursor_column()
        anchor = column_end(window, column) if window is not None else self.end_us
        fraction = (column + 1) / width
        self.span_us = span
        self._place(anchor + int((1 - fraction) * span))

    def action_now(self) -> None:
        self.cursor = None
        self._place(self.now_us)

    def action_whole(self) -> None:
        """The smallest zoom that holds the whole history (up to seven days), ending now."""
        if self.extent is None:
            self._whole = True  # once the history's extent is known
            return
        length = self.now_us - self.extent[0]
        self.span_us = next((z for z in ZOOMS_US if z >= length), ZOOMS_US[-1])
        self.cursor = None
        self._place(self.now_us)

    def action_signals(self) -> None:
        if not self.known:
            self.app.notify("the history's signals are still being read", timeout=3)
            return

        def chosen(names: tuple[str, ...] | None) -> None:
            if names is not None:
                self.show(names)
        self.app.push_screen(TrendSignalDialog(tuple(self.known), tuple(self.signals), {}),
                             chosen)

    def show(self, names: Sequence[str]) -> None:
        self.signals = list(names)
        self.request()

    def toggle_signal(self, name: str) -> None:
        self.show([n for n in self.signals if n != name] if name in self.signals
                  else [*self.signals, name])

    def zoom_to(self, span_us: int) -> None:
        self.span_us = span_us
        self._place(self.end_us)

    # -- the command palette -------------------------------------------------------------------
    def palette_entries(self) -> list[PaletteEntry]:
        from functools import partial

        from hmi.ui.palette import PaletteEntry
        entries = [PaletteEntry("Trends: back to the cell  [esc]", "Close the trends",
                                self.action_close),
                   PaletteEntry("Trends: choose signals…  [g]", "Tick the signals to draw",
                                self.action_signals),
                   PaletteEntry("Trends: now  [end]", "The window ends now and follows the "
                                "cell", self.action_now),
                   PaletteEntry("Trends: the whole history  [home]", "Zoom out to all of "
                                "it (at most 7 days)", self.action_whole)]
        for span in ZOOMS_US:
            entries.append(PaletteEntry(f"Trends: zoom to {zoom_text(span)}",
                                        "The window's length", partial(self.zoom_to, span)))
        devices: dict[str, list[str]] = {}
        for signal in self.known:
            if signal.group == "maintenance" and signal.device:
                devices.setdefault(signal.device, []).append(signal.name)
        for device, names in devices.items():
            entries.append(PaletteEntry(f"Trends: maintenance of {device}",
                                        "Its travel times and operations, over the history",
                                        partial(self.maintenance, names)))
        shown = set(self.signals)
        for signal in self.known:
            verb = "hide" if signal.name in shown else "show"
            entries.append(PaletteEntry(f"Trends: {verb} {signal.name}", signal.description,
                                        partial(self.toggle_signal, signal.name)))
        return entries

    def maintenance(self, names: Sequence[str]) -> None:
        self.signals = list(names)
        self.action_whole()
