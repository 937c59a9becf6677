"""The footer: every binding visible, wrapped on two lines when one line is too short.

Textual's footer is one line that scrolls sideways; at 80 columns, or at 120 in manual mode,
some of the operator's controls would be off screen. When the keys do not fit on one line
this footer takes the class ``-wrap`` (see ``app.tcss``) and lays them out in a grid of two
rows, or three when two are too wide (80 columns in manual mode, where the I/O keys join),
each column as wide as its widest key, so every control stays visible.
"""

from __future__ import annotations

from math import ceil
from typing import Any

from rich.cells import cell_len
from textual.app import ComposeResult
from textual.screen import Screen
from textual.widgets import Footer

from hmi.ui.containment import ContainedPump
from hmi.ui.textual_adapter import (
    FooterKey,
    bindings_ready,
    drop_closed_watchers,
    set_bindings_ready,
)

ROWS_WHEN_WRAPPED = 2
MAX_ROWS = 4
PALETTE_WIDTH = 13  # "▏^p palette" and its padding, docked on the right


def key_width(key: FooterKey) -> int:
    # the key, a space, the description, a space before the next key
    return cell_len(key.key_display) + 1 + cell_len(key.description) + 1


class HmiFooter(ContainedPump, Footer):
    needed = 0  # columns one line would need for every key
    _recompose_due = False
    _shown: tuple[Any, ...] | None = None  # what the keys on screen were composed from

    def bindings_changed(self, screen: Screen[Any]) -> None:
        """One recompose for every change of the bindings until the next refresh.

        Textual's footer schedules a recompose per change; the start and a focus move
        change the bindings several times in one refresh, and each recompose built and
        styled every key again: 4 recomposes before the valve's first frame, 2 now (with
        the keys below, 498 style applications in the app's start, 228 now). The one
        recompose reads the bindings as they are then, the last change included."""
        set_bindings_ready(self)
        if not screen.app.app_focus:
            return
        covered = screen is not screen.app.screen
        if self.is_attached and screen is self.screen:
            # A dialog (or the palette) over this screen: its keys stay, dimmed as disabled
            # keys are (they are, until it closes), instead of giving way to a one-line
            # footer that made the whole screen lay itself out again as the dialog opened,
            # and again as it closed. Its closing publishes the bindings again (Textual's
            # stack_updates), and the keys are those of then.
            self.set_class(covered, "-covered")
        if covered or self._recompose_due:
            return
        if self.is_attached and screen is self.screen:
            self._recompose_due = True
            self.call_after_refresh(self._recompose_once)

    async def _recompose_once(self) -> None:
        """Recompose, unless the keys would be the ones shown: the bindings change with the
        focus, but most moves (the I/O table to the alarm list and back, a dialog closing)
        end on the same keys; 77 of 186 recomposes in the pilot tests of the app built the
        same keys again, each with a layout and a repaint of the screen."""
        self._recompose_due = False
        shown = self.composed_from()
        if shown == self._shown:
            return
        await self.recompose()

    def composed_from(self) -> tuple[Any, ...]:
        """Everything :meth:`Footer.compose` reads to build the keys:
        each shown binding's key, display, description, action, group, whether it is
        enabled, its tooltip; the command palette's key."""
        app = self.app
        active = self.screen.active_bindings
        keys = tuple((b.key, app.get_key_display(b), b.description, b.action, b.group,
                      enabled, tooltip)
                     for (_node, b, enabled, tooltip) in active.values() if b.show)
        palette = active.get(app.COMMAND_PALETTE_BINDING)
        return (bindings_ready(self), self.show_command_palette and app.ENABLE_COMMAND_PALETTE,
                keys, palette and palette[1:])

    def compose(self) -> ComposeResult:
        self._shown = self.composed_from()
        self._forget_removed_keys()
        children = list(super().compose())
        for child in children:
            # Born with the footer's value and its class: else each key's watcher adds the
            # class once it is mounted, which styles the key a second time.
            if isinstance(child, FooterKey):
                child.set_reactive(FooterKey.compact, self.compact)
                child.set_class(self.compact, "-compact", update=False)
        self._widths = [key_width(c) for c in children if isinstance(c, FooterKey)
                        and not c.has_class("-command-palette")]
        self.needed = sum(self._widths) + PALETTE_WIDTH
        self._wrap()
        yield from children

    def on_resize(self) -> None:
        self._wrap()

    def _forget_removed_keys(self) -> None:
        """Drop the removed keys from the footer's watchers (hmi.ui.textual_adapter).

        Each key binds the footer's ``compact`` (``data_bind``), which puts the key in the
        footer's list of watchers; Textual prunes that list only when ``compact`` changes,
        which it never does here. The footer recomposes whenever the bindings change (the
        focus moves, a dialog opens), so every key ever shown stayed alive: ~6 MB per
        virtual minute in a soak, without end in a long session."""
        drop_closed_watchers(self)

    def grid(self, rows: int) -> list[int]:
        """Column widths when the keys are laid out on `rows` lines (row-major, as the grid
        fills), each column as wide as its widest key."""
        columns = max(1, ceil(len(self._widths) / rows))
        widths = [0] * columns
        for index, width in enumerate(self._widths):
            widths[index % columns] = max(widths[index % columns], width)
        return widths

    def _wrap(self) -> None:
        """One line if it fits; else the fewest lines (2 or more) on which every key fits."""
        width = self.app.size.width
        wrap = self.needed > width
        self.set_class(wrap, "-wrap")
        if not wrap:
            self.styles.height = 1
            return
        rows = ROWS_WHEN_WRAPPED
        # the last column's trailing space and the palette key's own padding may touch
        while rows < MAX_ROWS and sum(self.grid(rows)) + PALETTE_WIDTH - 2 > width:
            rows += 1
        widths = self.grid(rows)
        self.styles.grid_size_columns = len(widths)
        self.styles.grid_columns = " ".join(str(w) for w in widths)
        self.styles.height = rows
