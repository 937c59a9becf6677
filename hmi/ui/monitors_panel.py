"""Stopwatch monitors (002): each task's location and its stopwatches against the window.

Per task, its location and its two stopwatches drawn against [alpha, beta, gamma]::

    ▶ conveyor  executing                            2 starts · 1 in time
      x ▕██████··┊·│·▏ 2.10/5 s   y ▕██████··┊·│·▏ 2.10 s in [3, 4]
    ✗ robot     FAULTY robot_fault
      x ▕███████████▏ 4.00/4 s    y ▕████····┊│·▏ 1.00 s in [2, 3]
      ✗ robot_fault at 3.000 s: x 3.000 s, y 1.000 s — cannot end in time …

Both bars share one scale, 0 to gamma (the bar's end): ``┊`` marks alpha and ``│`` beta.
``x`` (time since the task started) must stay under gamma; ``y`` (effective work, frozen
while the task is interrupted) must end between alpha and beta. A task that waits or runs is
normal and grey; an interrupted one is amber with ``‖``; a latched fault is red with ``✗``,
its label, and the stopwatch values at detection, which stay until a fault reset.

When the column has too few rows, the detection values go first (they are in the
explanation too), then each task takes one line (location, x bar, the fault label).
"""

from __future__ import annotations

from rich.style import Style
from rich.text import Text

from hmi.engine.monitors import MonitorState
from hmi.engine.stopwatch import Window
from hmi.timefmt import seconds
from hmi.ui.frame import Frame
from hmi.ui.panel import ColumnPanel, set_title
from hmi.ui.style import MUTED, STYLE, Level

BAR = 12
LOCATIONS = {
    "waiting": ("○", "waiting", Level.NORMAL),
    "executing": ("▶", "executing", Level.NORMAL),
    "interrupted": ("‖", "INTERRUPTED", Level.ATTENTION),
    "faulty": ("✗", "FAULTY", Level.ALARM),
}


def window_bar(value_us: int, m: MonitorState, width: int = BAR) -> str:
    """`value` on a 0..gamma scale: filled cells, then alpha (┊) and beta (│) marks."""
    gamma = max(1, m.gamma_us)

    def cell(us: int) -> int:
        return min(width - 1, us * width // gamma)

    filled = min(width, value_us * width // gamma)
    cells = ["█"] * filled + ["·"] * (width - filled)
    for us, mark in ((m.alpha_us, "┊"), (m.beta_us, "│")):
        k = cell(us)
        if k >= filled:
            cells[k] = mark
    return "▕" + "".join(cells) + "▏"


def _s(us: int) -> str:
    return f"{us / 1_000_000:.2f}"


def _fmt(us: int) -> str:
    """A bound in seconds, for a figure followed by " s" ("0.2", not "200m" and "200m s")."""
    return f"{us / 1_000_000:g}"


def location_cell(m: MonitorState, name_w: int) -> Text:
    symbol, word, level = LOCATIONS.get(m.location, ("?", m.location, Level.ATTENTION))
    text = Text()
    style = STYLE[level] if level is not Level.NORMAL else Style()
    text.append(f"{symbol} ", style=style)
    text.append(m.name.ljust(name_w), style=style + Style(bold=True) if level
                is not Level.NORMAL else Style(bold=m.running))
    text.append(f" {word}", style=style if level is not Level.NORMAL else MUTED)
    return text


def x_text(m: MonitorState) -> Text:
    late = m.x_us >= m.gamma_us
    text = Text("x ")
    text.append(window_bar(m.x_us, m), style=STYLE[Level.ALARM] if m.faulty else MUTED)
    text.append(f" {_s(m.x_us)}/{_fmt(m.gamma_us)} s", style=Style(bold=late))
    return text


def y_text(m: MonitorState) -> Text:
    text = Text("y ")
    text.append(window_bar(m.y_us, m), style=STYLE[Level.ALARM] if m.faulty else MUTED)
    text.append(f" {_s(m.y_us)} s in [{_fmt(m.alpha_us)}, {_fmt(m.beta_us)}]")
    return text


def detection_text(m: MonitorState) -> Text:
    d = m.detection
    text = Text()
    if d is None:
        return text
    text.append(f"✗ {m.label}", style=STYLE[Level.ALARM])
    window = Window(m.alpha_us, m.beta_us, m.gamma_us)
    text.append(f" at {seconds(d.time_us)} s: x {seconds(d.x_us)} s, y {seconds(d.y_us)} s"
                f" — {d.explain(window)}")
    return text


PLAIN_LOCATIONS = {"waiting": "waiting", "executing": "running", "interrupted": "STOPPED",
                   "faulty": "FAULT"}


def plain_monitor_lines(m: MonitorState, width: int, detail: int) -> list[Text]:
    """The operator's view of a task: its title, what it does, how long it has run against
    the time it may take, and the fault in words; no stopwatch or label names."""
    symbol, _word, level = LOCATIONS.get(m.location, ("?", m.location, Level.ATTENTION))
    style = STYLE[level] if level is not Level.NORMAL else Style()
    head = Text()
    head.append(f"{symbol} ", style=style)
    head.append(m.title, style=style + Style(bold=True) if level is not Level.NORMAL
                else Style(bold=m.running))
    head.append(f" · {PLAIN_LOCATIONS.get(m.location, m.location)}",
                style=style if level is not Level.NORMAL else MUTED)
    if detail == 0:
        return [head]
    times = Text("  time ")
    times.append(window_bar(m.x_us, m), style=STYLE[Level.ALARM] if m.faulty else MUTED)
    times.append(f" {_s(m.x_us)} of at most {_fmt(m.gamma_us)} s · worked {_s(m.y_us)} s, "
                 f"needs {_fmt(m.alpha_us)}-{_fmt(m.beta_us)} s")
    lines = [head, times]
    if m.detection is not None and detail >= 2:
        from hmi.explain.monitors import plain_reason
        lines.append(Text("  ✗ ", style=STYLE[Level.ALARM]).append(
            plain_reason(m.detection, m)))
    return lines


def monitor_lines(m: MonitorState, name_w: int, width: int, detail: int) -> list[Text]:
    """A task's lines: `detail` 2 = location, bars, detection; 1 = location and bars (the
    detection is in the explanation); 0 = one line (location, x bar, fault label)."""
    head = location_cell(m, name_w)
    if detail == 0:  # the fault label before the bar: the end of the line may be cut
        line = head
        if m.detection is not None:
            line.append(" ")
            line.append(m.label, style=STYLE[Level.ALARM])
        line.append("  ")
        line.append_text(x_text(m))
        return [line]
    if m.detection is not None:
        head.append(" ")
        head.append(m.label, style=STYLE[Level.ALARM])
    counts = f"{m.attempt} start{'s' if m.attempt != 1 else ''} · {m.completed} in time"
    if m.faults:
        counts += f" · {m.faults} faulty"
    if head.cell_len + len(counts) + 2 <= width:
        head.append(" " * (width - head.cell_len - len(counts)))
        head.append(counts, style=MUTED)
    bars = Text("  ")
    bars.append_text(x_text(m))
    y = y_text(m)
    if bars.cell_len + 3 + y.cell_len <= width:
        bars.append("   ")
        bars.append_text(y)
        lines = [head, bars]
    else:
        lines = [head, bars, Text("  ").append_text(y)]
    if m.detection is not None and detail >= 2:
        lines.append(Text("  ").append_text(detection_text(m)))
    return lines


class MonitorsPanel(ColumnPanel):
    """Every task monitor of the project; hidden when it has none."""

    def __init__(self, count: int, *, id: str | None = None):
        super().__init__(id=id)
        self.count = count
        self.display = count > 0

    def on_mount(self) -> None:
        self.border_title = f"Monitors · {self.count}"

    def min_lines(self) -> int:
        return max(1, self.count)

    def render_detail(self, frame: Frame, detail: int) -> Text:
        monitors = frame.snapshot.monitors
        text = Text(no_wrap=True, overflow="ellipsis")
        if not monitors:
            text.append("no monitor state yet", style=MUTED)
            return text
        width = max(30, self.content_size.width or 40)
        faulty = sum(1 for m in monitors if m.faulty)
        set_title(self, f"Monitors · {len(monitors)}"
                  + (f" · {faulty} faulty" if faulty else ""))
        name_w = max(len(m.name) for m in monitors)
        lines = [line for m in monitors for line in (
            monitor_lines(m, name_w, width, detail) if frame.engineering
            else plain_monitor_lines(m, width, detail))]
        return Text("\n", no_wrap=True, overflow="ellipsis").join(lines)
