"""Columns that never run together (at 80x24): the alarm list's priority and
time (`P1 10.830 s`, never `P110.830 s`), a diagnoser's name and state (`V1 A3`, never
`V1A3`). Every gap closes the run before it: a viewer of the SVG screenshots that drops the
spaces opening a run of text (librsvg, some browsers) still shows the gap. The I/O table
names an estimate in the operator's words, not by its identifier."""

from __future__ import annotations

import re

from rich.console import Console
from rich.text import Text

from hmi.project.diagnosers import diagnosers_of
from hmi.ui.alarm_list import alarm_row
from hmi.ui.diagnosers_panel import PartitionInfo, diagnoser_lines
from tests.conftest import PROJECTS, make_session

S = 1_000_000


def runs(text: Text) -> list[str]:
    console = Console(width=400, color_system="truecolor", force_terminal=True)
    return [seg.text for seg in text.render(console) if seg.text]


def opening_gaps(text: Text) -> list[str]:
    """Runs that start with a space and go on with text: such a gap is lost in the SVG."""
    return [run for run in runs(text) if run[:1] == " " and run.strip()]


def faulty_valve():
    session = make_session(PROJECTS / "cispi_valve", inject=["F13@10.4s"])
    session.run_for(22 * S)
    return session


def test_alarm_rows_keep_a_gap_between_every_column_at_every_width():
    snap = faulty_valve().last
    assert len(snap.alarms) >= 2
    for alarm in snap.alarms:
        for width, device_w in ((76, 0), (156, 9)):
            row = alarm_row(alarm, width, device_w, 6)
            assert not opening_gaps(row), (width, runs(row))
            assert re.search(r"P[1-3] +\d+\.\d{3} s  ", row.plain), row.plain


def test_diagnoser_rows_keep_a_gap_between_name_state_and_decision():
    session = faulty_valve()
    snap = session.last.snapshot
    project = session.engine.project
    partitions = {p.flag: PartitionInfo(p.flag, p.sensor, p.estimate, p.actuators)
                  for spec in diagnosers_of(project) for p in spec.partitions}
    (d,) = snap.diagnosers
    assert d.faulty
    for detail in (0, 1, 2):
        lines = diagnoser_lines(d, partitions, set(snap.reconstructed), set(snap.masked), 2,
                                detail)
        for line in lines:
            assert not opening_gaps(line), (detail, runs(line))
        assert re.match(rf"✗ V1 +{d.state} ", lines[0].plain), lines[0].plain
        assert "}?" not in "".join(line.plain for line in lines)
