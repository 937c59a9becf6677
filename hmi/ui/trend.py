"""A trend drawn as text: what the historian kept of chosen signals over minutes to days.

Drawn with Rich text of our own rather than a plotting library (textual-plotext was tried,
docs/history.md says why not): a row per signal, one column per slice of time, the glyphs of
the chronogram (hmi.ui.chronogram) so the two read the same, and nothing ever drawn where the
history knows nothing (``·``: the cell did not run, or history was lost).

    fso        1 │▁▁▐███▌▁▁▐███▌▁▁▐███▌▁▁▐████▌▁▁··········▁▐██▌
    O.travel 1.92│▁▁▂▂▂▂▂▂▂▂▂▂▂▂▂▃▃▃▃▃▃▃▃▃▃▃▃▄▄▄··········▄▄▅▅
    V1.state   N3│N1───N2──N3────N4─N5───F13·········N1──N2─
    alarms       │        ▲  ✓        ○
                 │┊12:00      ┊12:15      ┊12:30      ┊12:45

* **Booleans** as steps: ``█`` high, ``▁`` low, ``▐`` a rise, ``▌`` a fall inside the column,
  ``▒`` several changes (a pulse shorter than a column is never lost);
* **numbers** as an area whose height is the column's highest value (eighth blocks), on the
  scale of the window (its least and greatest value, shown beside it on a taller screen);
* **states** (enums) as their names where they change, ``─`` while they hold;
* **counters** (operations) as how many happened in each column, an area again;
* **events** on the time axis: ``▲`` an alarm raised or back, ``✓`` acknowledged, ``○``
  cleared, ``◆`` an operator action; coloured by the alarm's priority.

The cursor is a column: the values shown beside the names are those at its end (the last
sample of the column, carried), and the line under the axis lists its events. Everything is
computed from the :class:`~hmi.history.query.Window` the store gave (a handful of queries
per signal, whatever the window's length), so drawing costs the width, not the samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, tzinfo

from rich.style import Style
from rich.text import Text

from hmi.history.catalogue import BOOL, COUNTER, ENUM, Signal
from hmi.history.query import Column, Drawn, Window
from hmi.history.store import Event
from hmi.ui.chronogram import FALL, HIGH, LOW, MULTI, RISE
from hmi.ui.style import MUTED, STYLE, Level

UNKNOWN = "·"  # the history does not cover this column
EIGHTHS = " ▁▂▃▄▅▆▇█"
LABEL_W = 10
VALUE_W = 9
NUMBER_ROWS_MAX = 6  # a number's lines on a tall terminal
SEPARATOR = "│"
CURSOR = Style(reverse=True)
ZOOMS_US = (60_000_000, 5 * 60_000_000, 15 * 60_000_000, 3_600_000_000, 4 * 3_600_000_000,
            12 * 3_600_000_000, 86_400_000_000, 3 * 86_400_000_000, 7 * 86_400_000_000)
TICKS_US = (1_000_000, 2_000_000, 5_000_000, 10_000_000, 15_000_000, 30_000_000, 60_000_000,
            120_000_000, 300_000_000, 600_000_000, 900_000_000, 1_800_000_000,
            3_600_000_000, 7_200_000_000, 10_800_000_000, 21_600_000_000, 43_200_000_000,
            86_400_000_000)
EVENT_MARK = {"raised": "▲", "returned": "▲", "chattering": "▲", "acknowledged": "✓",
              "cleared": "○"}
SEVERITY_STYLE = {"high": STYLE[Level.ALARM], "medium": STYLE[Level.ATTENTION],
                  "low": STYLE[Level.ATTENTION]}


def zoom_text(window_us: int) -> str:
    minutes = window_us // 60_000_000
    if minutes < 60:
        return f"{minutes} min"
    hours = minutes // 60
    return f"{hours} h" if hours < 24 else f"{hours // 24} d"


def number_rows(drawn: Sequence[Drawn], room: int) -> int:
    """The lines each number (or counter) is drawn on: 3 or more when every signal then fits
    (the room shared out, up to NUMBER_ROWS_MAX: a tall terminal shows a travel time's drift
    finer), else 1."""
    numbers = sum(1 for d in drawn if d.signal.kind not in (BOOL, ENUM))
    if not numbers:
        return 1
    rows = (room - (len(drawn) - numbers)) // numbers
    return 1 if rows < 3 else min(rows, NUMBER_ROWS_MAX)


def plot_width(total: int) -> int:
    return max(10, total - LABEL_W - VALUE_W - 1)


def draw(window: Window, cursor: int, height: int, zone: tzinfo | None = None) -> Text:
    """The whole chart: signal rows, the events row, the axis, the cursor's line. `height`
    is the room in lines; signals that do not fit are counted on the last line. Times in
    `zone` (None: the machine's)."""
    text = Text(no_wrap=True, overflow="crop")
    room = max(1, height - 3)  # events, axis, cursor line
    rows = number_rows(window.drawn, room)
    shown: list[Drawn] = []
    used = 0
    for d in window.drawn:
        need = rows if d.signal.kind not in (BOOL, ENUM) else 1
        if used + need > room - (1 if len(shown) < len(window.drawn) - 1 else 0):
            break
        shown.append(d)
        used += need
    for d in shown:
        for line in signal_lines(d, cursor, rows):
            text.append_text(line)
            text.append("\n")
    if len(shown) < len(window.drawn):
        text.append(f"+{len(window.drawn) - len(shown)} more: a taller terminal, or fewer "
                    "signals (g)\n", style=MUTED)
    text.append_text(events_line(window, cursor))
    text.append("\n")
    text.append_text(axis_line(window, zone))
    text.append("\n")
    text.append_text(cursor_line(window, cursor, zone))
    return text


def _prefix(name: str, value: str, style: Style | None = None) -> Text:
    label = name if len(name) <= LABEL_W else name[:LABEL_W - 1] + "…"
    line = Text(label.ljust(LABEL_W), style=style or MUTED)
    line.append(value[-VALUE_W + 1:].rjust(VALUE_W - 1) + " ")
    line.append(SEPARATOR, style=MUTED)
    return line


def _with_cursor(line: Text, plot: str, cursor: int, unknown_style: bool = True) -> Text:
    start = len(line)
    line.append(plot)
    if unknown_style:
        # "no history here" greyed, so it never reads as a value
        for i, ch in enumerate(plot):
            if ch == UNKNOWN:
                line.stylize(MUTED, start + i, start + i + 1)
    if 0 <= cursor < len(plot):
        line.stylize(CURSOR, start + cursor, start + cursor + 1)
    return line


def value_at(columns: Sequence[Column], cursor: int) -> float | None:
    if not 0 <= cursor < len(columns):
        return None
    column = columns[cursor]
    return column.last if column.known else None


def signal_lines(d: Drawn, cursor: int, rows: int) -> list[Text]:
    """A signal's lines: one for an on/off signal or a state, `rows` for a number (its name
    and value, then its scale's greatest and, on the last, least value)."""
    signal, columns = d.signal, d.columns
    value = value_at(columns, cursor)
    shown = signal.text(value) if value is not None else "?"
    if signal.kind == BOOL:
        return [_with_cursor(_prefix(signal.name, shown), bool_glyphs(columns), cursor)]
    if signal.kind == ENUM:
        return [_with_cursor(_prefix(signal.name, shown), enum_glyphs(signal, columns),
                             cursor)]
    bands, low, high = (counter_bands(columns) if signal.kind == COUNTER
                        else number_bands(columns))
    if signal.kind == COUNTER and value is not None:
        per = increments(columns)[cursor] if 0 <= cursor < len(columns) else None
        shown = f"{int(value):,}" if per is None else f"+{int(per)}"
    plots = area(bands, rows, low, high)
    lines = []
    for k, plot in enumerate(plots):
        if k == 0:
            prefix = _prefix(signal.name, shown)
        elif k == 1:
            prefix = _prefix(_scale(signal, high), "", MUTED)
        elif k == rows - 1:
            prefix = _prefix(_scale(signal, low), "", MUTED)
        else:
            prefix = _prefix("", "", MUTED)
        lines.append(_with_cursor(prefix, plot, cursor))
    return lines


def _scale(signal: Signal, value: float | None) -> str:
    if value is None:
        return ""
    if signal.kind == COUNTER:
        return f" {value:g}/col"
    return " " + signal.text(value)


def bool_glyphs(columns: Sequence[Column]) -> str:
    out = []
    for c in columns:
        if not c.known:
            out.append(UNKNOWN)
            continue
        before, last = c.before, c.last
        if c.count == 0 or (c.count > 1 and c.low == c.high and before in (None, c.low)):
            out.append(UNKNOWN if last is None else (HIGH if last else LOW))
        elif c.count == 1 or c.low == c.high:
            if before is None or c.opens or before == last:
                out.append(UNKNOWN if last is None else (HIGH if last else LOW))
            else:
                out.append(RISE if last else FALL)
        else:
            out.append(MULTI)
    return "".join(out)


def enum_glyphs(signal: Signal, columns: Sequence[Column]) -> str:
    out = [" "] * len(columns)
    shown: float | None = None
    free = 0
    for k, c in enumerate(columns):
        if not c.known or c.last is None:
            out[k] = UNKNOWN
            shown = None
            continue
        if c.last != shown or (c.count > 1 and k >= free):
            label = signal.text(c.last)
            if c.count > 1 and c.before is not None and c.low != c.high:
                label = "▒" + label
            if k >= free:
                for j, ch in enumerate(label[: len(columns) - k]):
                    out[k + j] = ch
                free = k + len(label)
            shown = c.last
        elif k >= free:
            out[k] = "─"
    # labels written over unknown columns after them stay; unknown columns they did not
    # reach keep their dot
    return "".join(out)


def number_bands(columns: Sequence[Column]
                 ) -> tuple[list[tuple[float, float] | None], float | None, float | None]:
    """Each column's band: the least and greatest value it held (the value carried in, and
    its samples); None where unknown. With the window's least and greatest value."""
    bands: list[tuple[float, float] | None] = []
    for c in columns:
        if not c.known or c.last is None:
            bands.append(None)
            continue
        if not c.count:
            bands.append((c.last, c.last))
            continue
        low, high = c.low, c.high
        if c.before is not None and not c.opens:
            low, high = min(low, c.before), max(high, c.before)
        bands.append((low, high))
    known = [b for b in bands if b is not None]
    return (bands, min(b[0] for b in known) if known else None,
            max(b[1] for b in known) if known else None)


def increments(columns: Sequence[Column]) -> list[float | None]:
    """A counter's increase inside each column (None where unknown)."""
    out: list[float | None] = []
    for c in columns:
        if not c.known or c.last is None:
            out.append(None)
        elif c.before is None or c.opens:
            out.append(0.0 if not c.count else None)
        else:
            out.append(max(0.0, c.last - c.before))
    return out


def counter_bands(columns: Sequence[Column]
                  ) -> tuple[list[tuple[float, float] | None], float | None, float | None]:
    """A counter's increase in each column, as a band from zero."""
    values = increments(columns)
    known = [v for v in values if v is not None]
    return ([None if v is None else (0.0, v) for v in values], 0.0,
            max(known) if known else None)


def area(bands: Sequence[tuple[float, float] | None], rows: int,
         low: float | None = None, high: float | None = None) -> list[str]:
    """Each column's band drawn `rows` high on the scale from `low` (one eighth: a known
    value is never blank) to `high` (full), by default the bands' own: filled from the row
    holding the band's least value up to its greatest (eighths at the top, whole cells
    below: a terminal has no block filled from the top). A constant is full (one eighth if
    it is zero); an unknown column is ``·``."""
    lines = [[" "] * len(bands) for _ in range(rows)]
    known = [b for b in bands if b is not None]
    if low is None:
        low = min((b[0] for b in known), default=0.0)
    if high is None:
        high = max((b[1] for b in known), default=0.0)
    steps = rows * 8

    def level(v: float) -> int:
        if high == low:
            return steps if v else 1
        return 1 + round((v - low) / (high - low) * (steps - 1))
    for k, band in enumerate(bands):
        if band is None:
            lines[rows - 1][k] = UNKNOWN
            continue
        top, bottom = level(band[1]), level(band[0])
        floor = (bottom - 1) // 8  # the row (from the bottom) holding the least value
        for r in range(rows):  # r = 0 is the top row
            from_bottom = rows - 1 - r
            if from_bottom < floor:
                continue
            lines[r][k] = EIGHTHS[min(8, max(0, top - from_bottom * 8))]
    return ["".join(row) for row in lines]


def events_line(window: Window, cursor: int) -> Text:
    width = window.width
    marks = [" "] * width
    styles: list[Style | None] = [None] * width
    rank = {"high": 3, "medium": 2, "low": 1}
    best = [0] * width
    for e in window.events:
        c = column_of(window, e.t_us)
        if c is None:
            continue
        if e.type == "alarm":
            mark = EVENT_MARK.get(e.event)
            if mark is None:
                continue
            weight = 10 + rank.get(e.severity, 0) + (5 if mark == "▲" else 0)
            if weight > best[c]:
                best[c] = weight
                marks[c] = mark
                styles[c] = SEVERITY_STYLE.get(e.severity) if mark == "▲" else MUTED
        elif e.type == "action" and best[c] < 1:
            best[c] = 1
            marks[c] = "◆"
            styles[c] = MUTED
    line = _prefix("alarms", "")
    start = len(line)
    line.append("".join(marks))
    for c, style in enumerate(styles):
        if style is not None:
            line.stylize(style, start + c, start + c + 1)
    if 0 <= cursor < width:
        line.stylize(CURSOR, start + cursor, start + cursor + 1)
    return line


def column_of(window: Window, t_us: int) -> int | None:
    """The column whose span (a, b] holds `t_us` (None: outside the window)."""
    span = window.end_us - window.start_us
    if not window.start_us < t_us <= window.end_us or span <= 0:
        return None
    return max(0, -(-(t_us - window.start_us) * window.width // span) - 1)


def column_end(window: Window, c: int) -> int:
    return window.start_us + (c + 1) * (window.end_us - window.start_us) // window.width


def local(t_us: int, zone: tzinfo | None = None) -> datetime:
    """An instant in `zone` (None: the machine's local time)."""
    return datetime.fromtimestamp(t_us / 1e6, UTC).astimezone(zone)


def tick_step(window: Window, min_gap: int = 10) -> int:
    span = window.end_us - window.start_us
    for step in TICKS_US:
        if step * window.width // max(1, span) >= min_gap:
            return step
    return TICKS_US[-1]


def tick_label(t_us: int, step: int, span: int, zone: tzinfo | None = None) -> str:
    when = local(t_us, zone)
    if step >= 86_400_000_000:
        return when.strftime("%a %d")
    if span > 86_400_000_000 and when.hour == 0 and when.minute == 0:
        return when.strftime("%a %d")
    if step < 60_000_000:
        return when.strftime("%H:%M:%S")
    return when.strftime("%H:%M")


def axis_line(window: Window, zone: tzinfo | None = None) -> Text:
    width = window.width
    step = tick_step(window)
    span = window.end_us - window.start_us
    row = [" "] * width
    first = local(window.start_us, zone)
    # ticks at round local times: count from the local midnight before the window
    midnight = first.replace(hour=0, minute=0, second=0, microsecond=0)
    origin = int(midnight.timestamp() * 1e6)
    t = origin + ((window.start_us - origin) // step + 1) * step
    free = 0
    while t <= window.end_us:
        c = column_of(window, t)
        if c is not None:
            label = "┊" + tick_label(t, step, span, zone)
            if c >= free and c + len(label) <= width:
                row[c:c + len(label)] = label
                free = c + len(label) + 1
        t += step
    line = _prefix("", "")
    line.append("".join(row), style=MUTED)
    return line


def cursor_line(window: Window, cursor: int, zone: tzinfo | None = None) -> Text:
    """The cursor's instant and the events in its column."""
    end = column_end(window, cursor)
    start = column_end(window, cursor - 1) if cursor > 0 else window.start_us
    slice_us = end - start
    when = local(end, zone)
    stamp = when.strftime("%Y-%m-%d %H:%M:%S")
    if slice_us < 1_000_000:
        stamp += f".{when.microsecond // 1000:03d}"
    line = Text(f"cursor {stamp}", style="bold")
    line.append(f" (a column is {_length(slice_us)})", style=MUTED)
    inside = [e for e in window.events if start < e.t_us <= end and _shown(e)]
    if inside:
        first = inside[0]
        line.append("  ")
        mark = EVENT_MARK.get(first.event, "◆") if first.type == "alarm" else "◆"
        said = first.text if first.text.startswith(first.event) or not first.text else \
            f"{first.event}: {first.text}"
        if first.by:
            said += f" [by {first.by}]"
        line.append(f"{mark} {said}", style=SEVERITY_STYLE.get(first.severity, MUTED)
                    if mark == "▲" else Style())
        if len(inside) > 1:
            line.append(f"  (+{len(inside) - 1} more)", style=MUTED)
    return line


def _shown(event: Event) -> bool:
    return event.type == "action" or (event.type == "alarm" and event.event in EVENT_MARK)


def _length(us: int) -> str:
    if us < 1_000_000:
        return f"{us / 1000:.0f} ms"
    if us < 60_000_000:
        return f"{us / 1e6:.3g} s"
    if us < 3_600_000_000:
        return f"{us / 60e6:.3g} min"
    return f"{us / 3600e6:.3g} h"


def window_title(start_us: int, end_us: int, following: bool,
                 zone: tzinfo | None = None) -> str:
    span = end_us - start_us
    a, b = local(start_us, zone), local(end_us, zone)
    fmt = "%H:%M:%S" if span < 3_600_000_000 else "%H:%M"
    if a.date() != b.date() or span >= 86_400_000_000:
        text = f"{a.strftime('%a %d %H:%M')} – {b.strftime('%a %d %H:%M')}"
    else:
        text = f"{a.strftime('%Y-%m-%d')} {a.strftime(fmt)} – {b.strftime(fmt)}"
    return text + (" · following now" if following else "")
