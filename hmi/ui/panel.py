"""A text panel that re-lays the screen out only when its own height may have changed.

``Static.update`` asks for a full layout of the screen by default. At 20 frames a second
that was most of the UI's work (measured: ~8 ms per frame under a profiler) and, sharing the
interpreter with the scan thread, most of the scan jitter. Panels redraw their text every
frame but keep the same number of lines nearly always, so they ask for a layout only when
that number changes.
"""

from __future__ import annotations

from rich.text import Text
from textual.css.query import NoMatches
from textual.widget import Widget
from textual.widgets import Static

from hmi.ui.containment import ContainedPump
from hmi.ui.frame import Frame

TOP_SHARE = 0.6  # app.tcss: #top { max-height: 60% } of #body


def set_title(widget: Widget, title: str) -> None:
    """Set a border title only when it changes: setting it repaints the widget, and a panel
    that set it every frame would repaint every frame for nothing."""
    if widget.border_title != title:
        widget.border_title = title


class TextPanel(ContainedPump, Static):
    def __init__(self, *, id: str | None = None):
        super().__init__(id=id, markup=False)
        self._lines = -1
        self._shown: Text | None = None

    def show_text(self, text: Text) -> None:
        if self._shown is not None and text == self._shown:
            return  # nothing new to draw
        lines = text.plain.count("\n") + 1
        self.update(text, layout=lines != self._lines)
        self._lines = lines
        self._shown = text


class ColumnPanel(TextPanel):
    """A panel that shares the upper column with others (control, diagnosers, monitors) and
    draws with as much detail as fits rather than be cut off at the bottom.

    The upper row of panels may take at most TOP_SHARE of the body (app.tcss); the panels
    above this one in its column take what they take, and the ones below it keep at least
    their one-line-per-item form. Subclasses render at a detail level (the highest first)
    and say how many lines their least detailed form needs.
    """

    DETAILS: tuple[int, ...] = (2, 1, 0)

    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.frame: Frame | None = None
        self._room_used: int | None = None

    def render_detail(self, frame: Frame, detail: int) -> Text:
        raise NotImplementedError

    def min_lines(self) -> int:
        """Lines of the least detailed form (what a panel below needs at least)."""
        return 1

    @property
    def active(self) -> bool:
        return bool(self.display)

    def show(self, frame: Frame) -> None:
        self.frame = frame
        if self.active:
            self.show_text(self.render_frame(frame))
            # The room is measured on the last layout; this frame may change it (an alarm
            # row, a banner): look again once it is laid out.
            self.call_after_refresh(self.recheck)

    def on_resize(self) -> None:
        if self.frame is not None and self.active:
            self.show_text(self.render_frame(self.frame))

    def recheck(self) -> None:
        """Draw again if the room changed since the last drawing (see app.Body)."""
        if self.frame is not None and self.active and self.room() != self._room_used:
            self.show_text(self.render_frame(self.frame))

    def render_frame(self, frame: Frame) -> Text:
        room = self._room_used = self.room()
        text = Text()
        for detail in self.DETAILS:
            text = self.render_detail(frame, detail)
            if room is None or text.plain.count("\n") + 1 <= room:
                break
        return text

    def room(self) -> int | None:
        """Lines this panel can show (None before the first layout)."""
        try:
            body = self.screen.query_one("#body")
        except NoMatches:
            return None
        if not body.size.height or self.parent is None:
            return None
        used, below = 0, False
        for sibling in self.parent.children:
            if sibling is self:
                below = True
            elif not sibling.display:
                continue
            elif not below:
                used += sibling.outer_size.height
            elif isinstance(sibling, ColumnPanel):
                used += sibling.min_lines() + 2
        return int(body.size.height * TOP_SHARE) - used - 2
