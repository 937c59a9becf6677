"""The footer: every binding visible, wrapped on two lines when the terminal is narrow.

Textual's footer is one line that scrolls sideways; at 80 columns half of the operator's
controls would be off screen. On a narrow screen (``Screen.-narrow``, see ``app.tcss``) this
footer lays its keys out in a two-row grid instead, each column as wide as its widest key,
so every control stays visible.
"""

from __future__ import annotations

from math import ceil

from rich.cells import cell_len
from textual.app import ComposeResult
from textual.widgets import Footer
from textual.widgets._footer import FooterKey

ROWS_WHEN_NARROW = 2


class HmiFooter(Footer):
    def compose(self) -> ComposeResult:
        children = list(super().compose())
        keys = [c for c in children if isinstance(c, FooterKey)
                and not c.has_class("-command-palette")]
        columns = max(1, ceil(len(keys) / ROWS_WHEN_NARROW))
        widths = [0] * columns
        for index, key in enumerate(keys):
            # key, a space, the description, a space before the next key
            width = cell_len(key.key_display) + 1 + cell_len(key.description) + 1
            widths[index % columns] = max(widths[index % columns], width)
        self.styles.grid_size_columns = columns
        self.styles.grid_columns = " ".join(str(w) for w in widths)
        yield from children
