"""The fault scenarios of the sorting and palletizer cells, each run once for the test modules
that assert on them: tests/test_cells.py (the damage each does, the cells' counters) and
tests/test_cell_monitors.py (the monitor labels and their instants).

Both modules ran the same 13 scenarios on their own (about 8 CPU s twice). A run is kept per
process (`functools.cache`); the tests that read one carry the mark `SHARED`, which puts them
on one pytest-xdist worker (tests/conftest.py schedules by group), so each scenario runs once
in the suite. A run is a headless session on the simulated plant with the project's own
policy, exactly as `plchmi run --scenario` runs it; the tests only read what it returns.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import pytest

from hmi.engine.snapshot import Snapshot
from hmi.project.loader import load_project
from hmi.project.scenarios import scenarios_of
from hmi.session.session import Session
from hmi.session.view import CellView
from tests.conftest import PROJECTS, make_session

S = 1_000_000
SHARED = pytest.mark.xdist_group("cell-runs")


@dataclass(frozen=True)
class CellSession:
    last: Snapshot  # the last scan's snapshot
    damage: tuple[tuple[int, str], ...]  # damage events as (plant time, kind), in order
    unsafe_written: int  # outputs written that violated a constraint, over the run

    @property
    def damage_kinds(self) -> Counter:
        return Counter(kind for _, kind in self.damage)

    @property
    def counters(self) -> dict[str, int]:
        return dict(self.last.plant_counters)


@cache
def run(name: str, control: str = "normal", seconds: int = 60,
        inject: tuple[str, ...] = ()) -> CellSession:
    """A headless session of `seconds` virtual seconds, with faults as the command line
    writes them."""
    session = make_session(PROJECTS / name, control=control, inject=inject)
    damage: list[tuple[int, str]] = []
    unsafe = 0
    report_unsafe = 0  # the last built scan's; a quiet scan gave that very report again

    def on_scan(cell: CellView) -> None:
        nonlocal unsafe, report_unsafe
        snap = cell.snapshot
        damage.extend((e.time_us, e.kind) for e in snap.plant_events if e.damage)
        report_unsafe = snap.filter_report.unsafe_written if snap.filter_report is not None else 0
        unsafe += report_unsafe

    def on_quiet(count: int) -> None:  # (no plant event at a quiet scan: Engine.run)
        nonlocal unsafe
        unsafe += report_unsafe * count
    # on the quiet path, as `plchmi run` without a trace (hmi.session.run_report.RunCollector.quiet
    # counts a quiet scan's report the same way)
    last = session.run_for(seconds * S, on_scan, on_quiet)
    return CellSession(last.snapshot, tuple(damage), unsafe)


def scenario_run(name: str, scenario: str) -> CellSession:
    """The run of a scenario the project declares (its faults, its length)."""
    (found,) = [s for s in scenarios_of(load_project(PROJECTS / name)) if s.name == scenario]
    return run(name, seconds=found.duration_us // S,
               inject=tuple(str(i) for i in found.injections))


def run_quietly(session: Session, duration_us: int,
                on_scan: Callable[[CellView], None] | None = None) -> CellView:
    """`session.run_for` on the quiet path (as `plchmi run` without a trace): the same scans,
    but the snapshot of a scan with no news is not built (it would be the last one's again;
    tests/test_fastpath_session.py holds both paths to the same results). Its `on_scan`
    sees every scan with news, so no alarm is missed. Half the CPU of building them all."""
    return session.run_for(duration_us, on_scan, on_quiet=lambda _: None)
