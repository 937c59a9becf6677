"""The safety constraints: violated now, and recently (how often, last time), each with its
one-line explanation.

Every row says what the filter did about a violation, in a word beside the colour:

- ``✗ UNSAFE``  violated and written anyway (monitor policy, or no safe vector existed);
- ``✗ blocked`` violated, outputs held in the safe state (block policy, or a fallback);
- ``▲ corrected`` violated by the program's (or the operator's) orders, the filter changed them;
- ``· ×3 …``     not violated now; violated 3 times since the start, last at that time;
- ``✓``          never violated (listed only when there is room).

When space is short (80×24) only the violated and recently violated rows are listed, and a
clean history collapses into one line. A click on a row opens its explanation (while the
constraint is violated, or its alarm is listed).
"""

from __future__ import annotations

from dataclasses import dataclass

from rich.text import Text
from textual import events

from hmi.timefmt import seconds
from hmi.ui.alarm_list import SHORT
from hmi.ui.frame import Frame
from hmi.ui.messages import ExplainRequested
from hmi.ui.panel import TextPanel
from hmi.ui.style import MUTED, OK_SYMBOL, Level, tag


@dataclass(frozen=True)
class ConstraintInfo:
    name: str
    kind: str  # simple / combined
    expr: str
    description: str


def _state(frame: Frame, name: str) -> tuple[Text, int]:
    """The state word of a constraint now, and a sort rank (0 most urgent)."""
    snap = frame.snapshot
    report = snap.filter_report
    stats = frame.constraints.get(name)
    if report is not None and name in report.violated_names:
        if name in report.residual and not report.safe_state:
            return tag("UNSAFE", Level.ALARM), 0
        if report.safe_state:
            return tag("blocked", Level.ALARM), 0
        return tag("corrected", Level.ATTENTION), 1
    if stats is not None and stats.episodes:
        return Text(f"· ×{stats.episodes}", style=MUTED), 2
    return Text(OK_SYMBOL, style=MUTED), 3


def explanation_line(frame: Frame, info: ConstraintInfo) -> str:
    """The level-1 explanation: the engine's now while violated, else the last one of its
    last violation (kept by the recorder); the description for a constraint never violated
    (or one whose violations came without an explanation)."""
    for explanation in frame.cell.explanations:
        if explanation.key == f"constraint:{info.name}":
            return explanation.what or info.description
    stats = frame.constraints.get(info.name)
    if stats is not None and stats.what:
        return stats.what
    return info.description or info.expr


class ConstraintsPanel(TextPanel):
    """A click on a row asks for that constraint's explanation (ExplainRequested)."""

    def __init__(self, constraints: list[ConstraintInfo], *, id: str | None = None):
        super().__init__(id=id)
        self.constraints = constraints
        self.frame: Frame | None = None
        self.show_all = False  # every constraint, even never violated (when there is room)
        self.row_names: list[str] = []  # the constraint on each row, as last drawn
        self.violated = 0  # rows of constraints violated now (listed first)

    def on_click(self, event: events.Click) -> None:
        offset = event.get_content_offset(self)
        if offset is not None and 0 <= offset.y + self.scroll_y < len(self.row_names):
            name = self.row_names[int(offset.y + self.scroll_y)]
            self.post_message(ExplainRequested(f"constraint:{name}"))

    def on_mount(self) -> None:
        self.border_title = f"Constraints · {len(self.constraints)}"

    def wanted_lines(self) -> int:
        """Rows it lists now (the app gives it room before the I/O table)."""
        return len(self.row_names) or 1

    def needed_lines(self) -> int:
        """Rows it must show: the constraints violated now (at least one line)."""
        return max(self.violated, 1)

    def show(self, frame: Frame) -> None:
        self.frame = frame
        self.set_class(self.app.size.height < SHORT, "-compact")
        self.show_all = self.app.size.height >= 40
        self.show_text(self.render_frame(frame))

    def render_frame(self, frame: Frame) -> Text:
        text = Text(no_wrap=True, overflow="ellipsis")
        self.row_names = []
        self.violated = 0
        if frame.snapshot.filter_report is None and not frame.constraints:
            text.append("no filter report yet", style=MUTED)
            return text
        rows = []
        for index, info in enumerate(self.constraints):
            word, rank = _state(frame, info.name)
            if rank == 3 and not self.show_all:
                continue
            rows.append((rank, index, info, word))
            self.violated += rank < 2
        if not rows:
            text.append(f"{OK_SYMBOL} none violated since the start", style=MUTED)
            return text
        # the rule's name only in the engineering view: its explanation (or description)
        # says what it is in words
        name_w = max(len(info.name) for _, _, info, _ in rows) if frame.engineering else -1
        for i, (rank, _, info, word) in enumerate(sorted(rows, key=lambda r: r[:2])):
            if i:
                text.append("\n")
            self.row_names.append(info.name)
            stats = frame.constraints.get(info.name)
            if frame.engineering:
                text.append(info.name.ljust(name_w) + " ",
                            style="bold" if rank < 2 else MUTED)
            cell = word.copy()
            cell.pad_right(12 - cell.cell_len)
            text.append_text(cell)
            since = None if stats is None else stats.since_us if rank < 2 else stats.last_us
            if since is not None:
                word_t = "since" if rank < 2 else "last"
                text.append(f"{word_t} {seconds(since)} s ", style=MUTED)
            style = "" if rank < 2 else MUTED
            text.append(explanation_line(frame, info), style=style)
        return text
