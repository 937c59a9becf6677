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

from concurrent.futures import Future, ProcessPoolExecutor

import pytest

from hmi.plant.sim import Injection
from hmi.project.campaign import campaign_of
from hmi.project.loader import load_project
from hmi.project.scenarios import scenarios_of
from hmi.studies.campaign import CONFIGS
from tests.conftest import PROJECTS, processes_for_a_test
from tests.export_harness import Agreement, Twin, engine_for

pytestmark = pytest.mark.slow  # a long study: tests/conftest.py, _studies_left_out

LONG_US = 30_000_000  # the faulty programs' runs
# A campaign run is compared up to this long after its fault, not to the campaign's end: on
# the valve's 48 runs, the last new situation (every Boolean of the image, the violations,
# the latch, each diagnoser's state and labels) appears at most 10.8 s after the fault
# (measured on the engine over the whole 40 s runs), so the rest of a run repeats situations
# already compared; the margin is 4 s. It cuts the valve's campaign scans by about a third.
AFTER_FAULT_US = 15_000_000
_TWINS: dict[str, Twin] = {}


def _twin(name: str) -> Twin:
    if name not in _TWINS:
        _TWINS[name] = Twin(load_project(PROJECTS / name))
    return _TWINS[name]


def _run(name: str, injections: tuple[Injection, ...], until_us: int, policy: str | None,
         diagnosis: str, control: str | None) -> Agreement:
    """One trace, in a worker: the engine and the export side by side (asserts inside)."""
    twin = _twin(name)
    engine = engine_for(twin.project, injections, policy=policy, control=control,
                        diagnosis=diagnosis)
    return twin.run(engine, until_us)


@pytest.fixture(scope="module")
def pool():
    with ProcessPoolExecutor(max_workers=processes_for_a_test()) as executor:
        yield executor


def _traces(name: str, faulty_policies: tuple[str, ...] = ("correct", "block", "monitor"),
            scenarios: tuple[str, ...] | None = None, campaign: bool = True) -> list[tuple]:
    """The runs of one project: its campaign, its scenarios, its faulty program."""
    project = load_project(PROJECTS / name)
    runs = []
    spec = campaign_of(project)
    if spec is not None and campaign:
        for s in spec.scenarios:
            for c in CONFIGS:
                runs.append((name, (Injection(s.fault, s.at_us, s.device),),
                             min(spec.length_us, s.at_us + AFTER_FAULT_US), c.policy,
                             c.diagnosis, None))
    for s in scenarios_of(project):
        if scenarios is None or s.name in scenarios:
            runs.append((name, s.injections, s.duration_us or LONG_US, None, "ftc", None))
    if "faulty" in project.controls:
        runs += [(name, (), LONG_US, policy, "ftc", "faulty") for policy in faulty_policies]
    return runs


def _all(pool, runs: list[tuple]) -> Agreement:
    futures: list[Future] = [pool.submit(_run, *run) for run in runs]
    total = Agreement()
    for future in futures:
        total.add(future.result())  # an AssertionError names the scan that disagreed
    return total


def test_the_valve_campaign_and_faulty_program_agree(pool):
    runs = _traces("cispi_valve")
    total = _all(pool, runs)
    assert len(runs) == 16 * 3 + 3
    period = load_project(PROJECTS / "cispi_valve").scan_period_us
    assert total.scans == sum(until // period + 1 for _, _, until, *_ in runs)
    assert total.scans > 48 * 2000 + 3 * 3001  # at least 20 s a campaign run
    # the runs reach most of the automaton and every policy's behaviour
    assert len(total.diagnoser_states) >= 25, sorted(total.diagnoser_states)
    assert total.corrected > 1000 and total.latched > 1000 and total.violations > 1000


def test_the_conveyor_robot_scenarios_agree(pool):
    runs = _traces("conveyor_robot")
    total = _all(pool, runs)
    assert len(runs) == 7
    assert total.scans == 7 * 1201 and total.monitor_faults > 1000


def test_the_sorting_cell_traces_agree(pool):
    runs = _traces("sorting")
    total = _all(pool, runs)
    assert len(runs) == 7 + 3
    assert total.corrected > 10_000 and total.monitor_faults > 10_000 and total.tested >= 4


def test_the_palletizer_and_subsystem_agree(pool):
    runs = (_traces("palletizer", ("correct",), ("pusher_home_stuck1",), campaign=False)
            + _traces("cispi_subsystem", ("correct",), ("v1_jam",), campaign=False))
    total = _all(pool, runs)
    assert len(runs) == 4
    assert total.corrected > 1000 and total.monitor_faults > 1000
