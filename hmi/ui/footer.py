"""The footer: every binding visible, wrapped on two lines when one line is too short.

Textual's footer is one line that scrolls sideways; at 80 columns, or at 120 in manual mode,
some of the operator's controls would be off screen. When the keys do not fit on one line
this footer takes the class ``-wrap`` (see ``app.tcss``) and lays them out in a two-row grid,
each column as wide as its widest key, so every control stays visible.
"""

from __future__ import annotations

from math import ceil

from rich.cells import cell_len
from textual.app import ComposeResult
from textual.widgets import Footer
from textual.widgets._footer import FooterKey

ROWS_WHEN_WRAPPED = 2
PALETTE_WIDTH = 13  # "▏^p palette" and its padding, docked on the right


def key_width(key: FooterKey) -> int:
    # the key, a space, the description, a space before the next key
    return cell_len(key.key_display) + 1 + cell_len(key.description) + 1


class HmiFooter(Footer):
    needed = 0  # columns one line would need for every key

    def compose(self) -> ComposeResult:
        children = list(super().compose())
        keys = [c for c in children if isinstance(c, FooterKey)
                and not c.has_class("-command-palette")]
        columns = max(1, ceil(len(keys) / ROWS_WHEN_WRAPPED))
        widths = [0] * columns
        for index, key in enumerate(keys):
            widths[index % columns] = max(widths[index % columns], key_width(key))
        self.styles.grid_size_columns = columns
        self.styles.grid_columns = " ".join(str(w) for w in widths)
        self.needed = sum(key_width(k) for k in keys) + PALETTE_WIDTH
        self._wrap()
        yield from children

    def on_resize(self) -> None:
        self._wrap()

    def _wrap(self) -> None:
        self.set_class(self.needed > self.app.size.width, "-wrap")
