"""The I/O table: inputs as read; outputs with their functional value (FOV) beside the value
written, so a difference — the filter, the safe-state latch, a masked actuator — shows at a
glance, with the reason in words. A sensor the diagnosers distrust reads
``≈ estimated open position`` (the filter reads its estimate), an order they mask
``⊘ masked by the diagnosis``, an output of a device the operator stopped ``▲ stopped``. In
a narrow panel the marks are ``≈ estimated`` and ``⊘ masked``. The identifiers (``fso_hat``,
``def_V``) are the diagnosers panel's, for the engineer.

The Description column comes last: at 80 columns it is cut to a few letters, so the
highlighted signal's whole description is on the table's lower border.

The table is also where the operator picks an output for a manual request (keys 1 / 0 / x
on the highlighted row) or presses a simulated push button (b). It does not send anything
itself: it posts :class:`~hmi.ui.messages.CommandRequested` up to the app.
"""

from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.binding import Binding
from textual.widgets import DataTable

from hmi.engine.commands import ManualOutput, SetInput
from hmi.engine.layout import Layout
from hmi.explain.plain import lower_first, without_notes
from hmi.ui.containment import ContainedPump
from hmi.ui.frame import Frame
from hmi.ui.messages import CommandRequested
from hmi.ui.style import MUTED, STYLE, Level, bit, tag
from hmi.ui.textual_adapter import drop_stale_renders

COLUMNS = (("signal", "Signal"), ("dir", "I/O"), ("fov", "FOV"), ("value", "Value"),
           ("state", "State"), ("description", "Description"))
MANUAL_ACTIONS = ("manual_on", "manual_off", "manual_release")
NARROW = 60  # panel width (cells) under which the State marks take their short form


class IOPanel(ContainedPump, DataTable[Any]):
    BINDINGS = [
        Binding("1", "manual_on", "On", tooltip="Manual: request the highlighted output on"),
        Binding("0", "manual_off", "Off", tooltip="Manual: request the highlighted output off"),
        Binding("x", "manual_release", "Release",
                tooltip="Manual: release the request (the output returns to 0)"),
        Binding("b", "button", "Button",
                tooltip="SIMULATION: press / release the highlighted push button"),
    ]

    def __init__(self, layout: Layout, descriptions: dict[str, str],
                 free_inputs: tuple[str, ...], *, id: str | None = None,
                 devices: dict[str, str] | None = None, partitions: tuple[Any, ...] = (),
                 row_descriptions: dict[str, str] | None = None):
        super().__init__(id=id, cursor_type="row", zebra_stripes=False)
        self.layout_ = layout
        self.descriptions = descriptions
        # the rows' Description cells (the app leaves out a device name every row repeats:
        # at 80 columns "Valve" on every row said nothing); the border keeps the whole
        # description of the highlighted row
        self.row_descriptions = row_descriptions or descriptions
        self.free_inputs = free_inputs
        self.devices = devices or {}  # output -> its device (for devices the operator stops)
        # diagnoser partitions: sensor -> its estimate; output -> the flags that mask it
        self.estimates = {p.sensor: p.estimate for p in partitions if p.sensor}
        self.mask_flags: dict[str, list[str]] = {}
        for p in partitions:
            for out in p.actuators:
                self.mask_flags.setdefault(out, []).append(p.flag)
        self.frame: Frame | None = None
        self._cells: dict[tuple[str, str], object] = {}
        self._widths: dict[str, int] = {}
        self._changed = False  # (a cell changed in this frame)
        self._manual = False
        self.subject_rows: list[str] = []  # what the alarm explained is about (reveal)

    def on_mount(self) -> None:
        self.border_title = "I/O"
        for key, label in COLUMNS:
            self.add_column(label, key=key)
            self._widths[key] = len(label)
        for name in self.layout_.inputs:
            self.add_row(name, "in", "", "", "", self.row_descriptions.get(name, ""), key=name)
        for name in self.layout_.outputs:
            self.add_row(name, "out", "", "", "", self.row_descriptions.get(name, ""),
                         key=name)
        if self.layout_.outputs:
            self.move_cursor(row=len(self.layout_.inputs))

    # -- display -----------------------------------------------------------------------------
    def show(self, frame: Frame) -> None:
        self.frame = frame
        self._changed = False
        snap = frame.snapshot
        if frame.manual_keys != self._manual:
            self._manual = frame.manual_keys
            self.refresh_bindings()
        reconstructed, masked = set(snap.reconstructed), set(snap.masked)
        # In a narrow panel (80 columns) the State column has about ten cells: the marks keep
        # their symbol and the one name that matters, not the sentence around it.
        narrow = 0 < self.size.width < NARROW
        for name in snap.layout.inputs:
            value = snap.value(name)
            state: list[Text] = []
            if not snap.plant.connected:
                state.append(tag("stale", Level.ALARM))  # the last value read, not the plant's
            if name in reconstructed:
                # The operator's words, not the estimate's identifier (fso_hat): "estimated",
                # or with room the estimate's own plain name ("estimated open position").
                estimate = self.estimates.get(name)
                plain = lower_first(without_notes(self.descriptions.get(estimate, ""))) \
                    if estimate else ""
                text = f"≈ {plain}" if plain and not narrow else "≈ estimated"
                state.append(Text(text, style=STYLE[Level.ATTENTION]))
            if name in self.free_inputs:
                state.append(tag("button " + ("pressed" if value else "up"),
                                 Level.SIMULATION))
            self._set(name, "value", bit(value))
            self._set(name, "state", _join(state))
        requests = dict(snap.manual)
        set_flags = {f for d in snap.diagnosers for f, v in d.flags if v}
        for name, fov, written in zip(snap.layout.outputs, snap.fov, snap.outputs, strict=True):
            state = []
            differs = name in frame.changed
            reason = frame.changed.get(name)
            if name in masked:
                flags = ", ".join(f for f in self.mask_flags.get(name, ())
                                  if f in set_flags)
                text = "⊘ masked by the diagnosis" if flags and not narrow else "⊘ masked"
                state.append(Text(text, style=STYLE[Level.ALARM]))
                if reason is not None and reason.startswith("masked"):
                    reason = None  # the mark says it (the FOV cell shows the difference)
            if reason is not None:
                level = Level.ALARM if snap.latched else Level.ATTENTION
                state.insert(0, tag("≠ " + reason, level))
            if self.devices.get(name) in snap.stopped_devices:
                state.append(tag("stopped", Level.ATTENTION))
            if frame.manual:
                if name in requests:
                    state.append(tag(f"forced {bit(requests[name])}", Level.ATTENTION))
                else:
                    state.append(Text("no request", style=MUTED))
            fov_style = STYLE[Level.ATTENTION] if differs else MUTED
            self._set(name, "fov", Text(bit(fov), style=fov_style))
            self._set(name, "value", Text(bit(written), style="bold" if written else ""))
            self._set(name, "state", _join(state))
        if self._changed:
            drop_stale_renders(self)

    def reveal_subject(self, names: list[str]) -> None:
        """The rows the alarm explained is about: scrolled to now, and again when the table's
        height changes (the layout settles after the frame that changed the subject)."""
        self.subject_rows = names
        self.call_after_refresh(self.reveal, names)

    def reveal(self, names: list[str]) -> bool:
        """Scroll so that the rows of `names` (what the alarm explained is about, the most
        important first) are on screen: the first for sure, and as many of the others as
        fit around it; the cursor stays where the operator left it. At 80x24 the table may
        show one to three rows. False if nothing had to move (or none is a row)."""
        rows = [self.get_row_index(n) for n in dict.fromkeys(names) if n in self.rows]
        height = self.scrollable_content_region.height - (self.header_height
                                                          if self.show_header else 0)
        if not rows or height <= 0:
            return False
        first = rows[0]

        def seen(top: int) -> int:
            return sum(top <= r < top + height for r in rows)
        top = round(self.scroll_y)
        starts = range(max(0, first - height + 1), first + 1)
        best = max(starts, key=lambda start: (seen(start), start))  # the first on top
        if top == best:
            return False
        self.scroll_to(y=best, animate=False, immediate=True)
        return True

    def on_resize(self) -> None:
        # The short or long form of the marks depends on the width: redraw on the last frame
        # (the layout may change after it was shown: a wider screen class, a resized terminal).
        if self.frame is not None:
            self.show(self.frame)
        if self.subject_rows:
            self.call_after_refresh(self.reveal, self.subject_rows)

    def _set(self, row: str, column: str, value: object) -> None:
        if column == "state" and isinstance(value, Text) and self.size.width >= NARROW:
            # A column widens to its longest text and never narrows: one long reason
            # ("≠ held safe: a safety rule was broken — …") pushed the Description column out
            # of a 160-column screen for good. A third of the panel; the rest is on the
            # explanation and the message line.
            cap = max(32, self.size.width // 3)
            if value.cell_len > cap:
                value = value.copy()
                value.truncate(cap, overflow="ellipsis")
        key = (row, column)
        if self._cells.get(key) != value:
            self._cells[key] = value
            # Widening a column re-lays the screen out: only ask when the text is wider.
            width = value.cell_len if isinstance(value, Text) else len(str(value))
            wider = width > self._widths.get(column, 0)
            if wider:
                self._widths[column] = width
            self.update_cell(row, column, value, update_width=wider)
            self._changed = True

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        """The highlighted signal's whole description on the border (a narrow table cuts
        its column to a few letters; names and values come first)."""
        name = event.row_key.value if event.row_key is not None else None
        text = f"{name}: {self.descriptions.get(name, '')}" if name else ""
        if self.border_subtitle != text:
            self.border_subtitle = text

    @property
    def selected(self) -> str | None:
        if self.row_count == 0:
            return None
        row_key, _ = self.coordinate_to_cell_key(self.cursor_coordinate)
        return row_key.value

    # -- actions -----------------------------------------------------------------------------
    def action_scroll_home(self) -> None:
        """Home: the first signal. A row table's Home and End are about rows; Textual's
        DataTable scrolls sideways on them, and End left only the descriptions' ends on
        screen at 80 columns, names, values and header scrolled away (seen in a soak)."""
        self.move_cursor(row=0, column=0)
        self.scroll_x = 0

    def action_scroll_end(self) -> None:
        """End: the last signal (names and values stay in view)."""
        self.move_cursor(row=max(self.row_count - 1, 0), column=0)
        self.scroll_x = 0

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if self.app.screen is not self.screen and action in (*MANUAL_ACTIONS, "button"):
            return False  # a dialog is open over the table
        if action in MANUAL_ACTIONS:
            return self._manual
        if action == "button":
            return bool(self.free_inputs)
        return True

    def _request(self, value: bool | None) -> None:
        name = self.selected
        if name is not None:
            self.post_message(CommandRequested(ManualOutput(name, value)))

    def action_manual_on(self) -> None:
        self._request(True)

    def action_manual_off(self) -> None:
        self._request(False)

    def action_manual_release(self) -> None:
        self._request(None)

    def action_button(self) -> None:
        name = self.selected
        if name is None or self.frame is None:
            return
        snap = self.frame.snapshot
        current = bool(snap.value(name)) if name in snap.layout.slots else False
        self.post_message(CommandRequested(SetInput(name, not current)))


def _join(parts: list[Text]) -> Text:
    return Text(" ").join(parts) if parts else Text("")
