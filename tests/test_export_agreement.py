"""The exported safety layer agrees with the engine on every scan of the example projects'
traces: the valve's whole fault campaign (every scenario under its three configurations) and
its faulty program under each policy, every scenario of the conveyor/robot cell, the sorting
cell's scenarios and faulty program, and a trace each of the palletizer and of the CISPI
subsystem (two component diagnosers, a renamed identifier).

Each trace runs the engine on its simulated plant and the exported Structured Text in the
tests' interpreter side by side (tests/export_harness.py); about 300,000 scans in all, spread
over two worker processes when the machine has two cores (one when pytest-xdist
already runs the suite on both).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import pytest

from hmi.project.loader import load_project
from tests.conftest import PROJECTS, processes_for_a_test
from tests.export_harness import Agreement, TraceRun, Twin, agree_on, export_traces

pytestmark = pytest.mark.slow  # a long study: tests/conftest.py, _studies_left_out

@pytest.fixture(scope="module")
def pool():
    with ProcessPoolExecutor(max_workers=processes_for_a_test()) as executor:
        yield executor


def _all(pool, runs: list[TraceRun]) -> Agreement:
    return agree_on(pool, runs, Twin)


def test_the_valve_campaign_and_faulty_program_agree(pool):
    runs = export_traces("cispi_valve")
    total = _all(pool, runs)
    assert len(runs) == 16 * 3 + 3
    period = load_project(PROJECTS / "cispi_valve").scan_period_us
    assert total.scans == sum(until // period + 1 for _, _, until, *_ in runs)
    assert total.scans > 48 * 2000 + 3 * 3001  # at least 20 s a campaign run
    # the runs reach most of the automaton and every policy's behaviour
    assert len(total.diagnoser_states) >= 25, sorted(total.diagnoser_states)
    assert total.corrected > 1000 and total.latched > 1000 and total.violations > 1000


def test_the_conveyor_robot_scenarios_agree(pool):
    runs = export_traces("conveyor_robot")
    total = _all(pool, runs)
    assert len(runs) == 7
    assert total.scans == 7 * 1201 and total.monitor_faults > 1000


def test_the_sorting_cell_traces_agree(pool):
    runs = export_traces("sorting")
    total = _all(pool, runs)
    assert len(runs) == 7 + 3
    assert total.corrected > 10_000 and total.monitor_faults > 10_000 and total.tested >= 4


def test_the_palletizer_and_subsystem_agree(pool):
    runs = (export_traces("palletizer", ("correct",), ("pusher_home_stuck1",), campaign=False)
            + export_traces("cispi_subsystem", ("correct",), ("v1_jam",), campaign=False))
    total = _all(pool, runs)
    assert len(runs) == 4
    assert total.corrected > 1000 and total.monitor_faults > 1000
