"""The trend's drawing (hmi.ui.trend), column by column: what each glyph says is what the
history holds, and nothing is drawn where it holds nothing."""

from __future__ import annotations

from datetime import UTC

from hypothesis import given
from hypothesis import strategies as st

from hmi.history.catalogue import BOOL, COUNTER, ENUM, NUMBER, Signal
from hmi.history.query import Column, Drawn, Window
from hmi.history.store import Event
from hmi.ui.chronogram import FALL, HIGH, LOW, MULTI, RISE
from hmi.ui.trend import (
    NUMBER_ROWS_MAX,
    UNKNOWN,
    area,
    axis_line,
    bool_glyphs,
    column_of,
    draw,
    enum_glyphs,
    events_line,
    increments,
    number_rows,
)

HOUR = 3_600_000_000
T0 = 1_790_000_000_000_000  # 2026-09-21 14:13:20 UTC


def known(before, count=0, low=0.0, high=0.0, last=None, opens=False) -> Column:
    return Column(True, before, count, low, high, before if last is None and not count
                  else last, opens)


def test_booleans_read_as_steps_edges_and_pulses():
    columns = [Column(False, None),  # before the history
               known(None, 1, 0, 0, 0.0, opens=True),  # the segment starts low
               known(0.0),  # held low
               known(0.0, 1, 1, 1, 1.0),  # a rise
               known(1.0),  # held high
               known(1.0, 2, 0, 1, 1.0),  # a pulse shorter than a column: never lost
               known(1.0, 1, 0, 0, 0.0),  # a fall
               Column(False, None)]  # the cell stopped
    assert bool_glyphs(columns) == UNKNOWN + LOW + LOW + RISE + HIGH + MULTI + FALL + UNKNOWN


def test_the_same_value_stored_again_is_no_change():
    # a segment that starts again (after a loss) stores every value anew
    assert bool_glyphs([known(1.0, 1, 1, 1, 1.0, opens=True)]) == HIGH
    assert bool_glyphs([known(1.0, 2, 1, 1, 1.0)]) == HIGH


def test_states_are_named_where_they_change():
    signal = Signal("V1.state", ENUM, "", "diagnoser", labels=("N1", "N2", "F13"))
    columns = [known(None, 1, 0, 0, 0.0, opens=True), known(0.0), known(0.0),
               known(0.0, 1, 1, 1, 1.0), known(1.0), known(1.0), known(1.0, 1, 2, 2, 2.0),
               known(2.0), known(2.0), Column(False, None)]
    assert enum_glyphs(signal, columns) == "N1─N2─F13" + UNKNOWN


def test_an_area_is_scaled_to_the_window_and_dots_the_unknown():
    rows = area([(1.0, 1.0), (2.0, 2.0), None, (3.0, 3.0)], 1)
    assert rows == ["▁▅" + UNKNOWN + "█"]
    tall = area([(0.0, 0.0), (1.5, 1.5), (3.0, 3.0), (2.9, 3.0)], 3)
    assert [row[0] for row in tall] == [" ", " ", "▁"]  # the least: one eighth
    assert [row[2] for row in tall] == ["█", " ", " "]  # the greatest: the top row's
    assert [row[1] for row in tall] == [" ", "▅", " "]  # the middle, in the middle row
    wide = area([(0.0, 3.0)], 3, 0.0, 3.0)
    assert [row[0] for row in wide] == ["█", "█", "█"]  # a column that swept the range
    assert area([(2.0, 2.0), (2.0, 2.0)], 1) == ["██"]  # a constant: drawn, not empty


def test_a_counter_counts_per_column():
    columns = [known(None, 1, 5, 5, 5.0, opens=True), known(5.0, 3, 6, 8, 8.0), known(8.0),
               Column(False, None)]
    assert increments(columns) == [None, 3.0, 0.0, None]


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 3), st.booleans()), min_size=1,
                max_size=60))
def test_every_column_has_one_glyph_and_an_unknown_one_says_so(spec):
    """Whatever the history: one glyph per column; `·` exactly where it knows nothing."""
    columns = []
    value = None
    for is_known, count, high in spec:
        if not is_known:
            columns.append(Column(False, None))
            value = None
            continue
        last = (1.0 if high else 0.0) if count else value
        columns.append(Column(True, value, count, 0.0 if count > 1 else (last or 0.0),
                              1.0 if count > 1 else (last or 0.0), last))
        value = last
    glyphs = bool_glyphs(columns)
    assert len(glyphs) == len(columns)
    for glyph, column in zip(glyphs, columns, strict=True):
        assert (glyph == UNKNOWN) == (not column.known or column.last is None)
        assert glyph in (UNKNOWN, HIGH, LOW, RISE, FALL, MULTI)


def _window(width=60, span=HOUR, events=()) -> Window:
    fso = Signal("fso", BOOL, "open end switch", "io")
    travel = Signal("O.travel", NUMBER, "opening time", "maintenance", unit="s")
    ops = Signal("O.operations", COUNTER, "openings", "maintenance")
    cols = [known(0.0 if k % 2 else None, 1, k % 2, k % 2, float(k % 2), opens=k == 0)
            for k in range(width)]
    travels = [known(1.9, 1, 1.9 + k / 1000, 1.9 + k / 1000, 1.9 + k / 1000)
               for k in range(width)]
    counts = [known(float(k), 1, k + 1, k + 1, float(k + 1)) for k in range(width)]
    return Window(T0, T0 + span, width, (Drawn(fso, tuple(cols)), Drawn(travel, tuple(travels)),
                                         Drawn(ops, tuple(counts))), tuple(events), ())


def test_events_sit_on_their_column_the_worst_shown():
    events = (Event(T0 + 30 * 60_000_000, "alarm", "raised", "k", "high", "jammed", "", {}),
              Event(T0 + 30 * 60_000_000 - 1, "action", "acknowledge", "", "", "", "", {}),
              Event(T0 + 45 * 60_000_000, "alarm", "acknowledged", "k", "high", "x", "", {}))
    window = _window(events=events)
    line = events_line(window, cursor=59).plain
    plot = line[line.index("│") + 1:]
    assert plot[column_of(window, events[0].t_us)] == "▲"
    assert plot[column_of(window, events[2].t_us)] == "✓"
    assert plot.count("◆") == 0  # the action shares the alarm's column: the alarm is shown


def test_the_axis_has_round_times_and_the_chart_fits_80_columns():
    window = _window()
    axis = axis_line(window, UTC).plain
    assert "┊14:15" in axis or "┊14:20" in axis
    text = draw(window, cursor=10, height=18, zone=UTC)
    lines = text.plain.splitlines()
    assert all(len(line) <= 80 for line in lines), max(map(len, lines))
    assert lines[0].startswith("fso") and "O.travel" in text.plain
    assert "cursor 2026-09-21" in lines[-1]
    # too little room: the signals that do not fit are counted, never silently dropped
    short = draw(window, cursor=10, height=5, zone=UTC).plain
    assert "+2 more" in short or "+1 more" in short


def test_numbers_take_the_room_a_tall_terminal_gives():
    """fso takes a line; the two numbers share the rest: one line each when three do not fit,
    three at 80x24's room, up to NUMBER_ROWS_MAX on a tall terminal; every signal is shown
    and each number's scale (greatest, least) is beside its first and last lines."""
    window = _window()
    for height, rows in ((6, 1), (10, 3), (18, NUMBER_ROWS_MAX), (42, NUMBER_ROWS_MAX)):
        assert number_rows(window.drawn, height - 3) == rows
        lines = draw(window, cursor=10, height=height, zone=UTC).plain.splitlines()
        assert lines[0].startswith("fso")
        assert lines[1].startswith("O.travel") and lines[1 + rows].startswith("O.operati")
        assert len(lines) == 1 + 2 * rows + 3  # and the events, axis and cursor lines
        if rows > 1:
            assert lines[2].split()[0] == "1.959" and lines[rows].split()[0] == "1.900"
