"""A text panel that re-lays the screen out only when its own height may have changed.

``Static.update`` asks for a full layout of the screen by default. At 20 frames a second
that was most of the UI's work (measured: ~8 ms per frame under a profiler) and, sharing the
interpreter with the scan thread, most of the scan jitter. Panels redraw their text every
frame but keep the same number of lines nearly always, so they ask for a layout only when
that number changes.
"""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Static


class TextPanel(Static):
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
