"""The exported program, compiled by an independent IEC 61131-3 compiler (matiec's iec2c, then
gcc: tests/matiec.py), agrees with the engine on every scan of every example project's
recorded traces: each project's fault campaign under its three configurations, its
scenarios, its faulty program under each policy (tests/export_harness.py, export_traces).
Compared at every scan: the outputs written, the violation word, the latch and the fallback,
the timers and observers, the partition flags and filtered sensors, each diagnoser's state
and labels, each monitor's location, stopwatches, counters and latched evidence. Every scan
that differs is counted and named, not only the first.

Without matiec's source beside the checkout (shared/tools/matiec, or $PLCHMI_MATIEC) or the
tools to build it (bison, flex, autoconf, automake, g++, make: .ci/run installs them), these
tests are skipped and say why.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import pytest

from hmi.export.build import build
from hmi.export.plcopen import write_plcopen
from hmi.export.st import write_st
from hmi.project.loader import load_project
from tests.conftest import PROJECTS, processes_for_a_test
from tests.export_harness import MatiecTwin, agree_on, engine_for, export_traces, shorter_ton1
from tests.matiec import MatiecUnavailable, compiler
from tests.plcopen_reader import st_from_plcopen

pytestmark = pytest.mark.slow  # a long study: tests/conftest.py, _studies_left_out

EXAMPLES = ("cispi_valve", "conveyor_robot", "sorting", "palletizer", "cispi_subsystem")


@pytest.fixture(scope="module")
def matiec():
    try:
        return compiler()
    except MatiecUnavailable as exc:
        pytest.skip(f"matiec cannot be had: {exc}")


@pytest.fixture(scope="module")
def pool():
    with ProcessPoolExecutor(max_workers=processes_for_a_test()) as executor:
        yield executor


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_trace_agrees_under_matiec(matiec, pool, name):
    runs = export_traces(name)
    assert runs, f"{name} has no trace to compare on"
    MatiecTwin(load_project(PROJECTS / name))  # compiled here, the workers read the cache
    total = agree_on(pool, runs, MatiecTwin)  # an AssertionError counts and names the scans
    period = load_project(PROJECTS / name).scan_period_us
    assert total.scans == sum(until // period + 1 for _, _, until, *_ in runs)
    print(f"{name}: {len(runs)} traces, {total.scans} scans, 0 mismatches "
          f"({total.violations} with a violation, {total.corrected} corrected, "
          f"{total.latched} latched, {total.monitor_faults} with a monitor fault, "
          f"{len(total.diagnoser_states)} diagnoser states)")


def test_the_plcopen_xml_compiles_and_agrees_under_matiec(matiec):
    """The XML target's ST bodies, assembled back into a file (tests/plcopen_reader.py),
    compile and run the same."""
    valve = load_project(PROJECTS / "cispi_valve")
    twin = MatiecTwin(valve, text=st_from_plcopen(write_plcopen(build(valve, "faulty"))),
                      control="faulty")
    result = twin.run(engine_for(valve, control="faulty"), 15_000_000, resets_after=(600,))
    assert result.scans == 1501 and result.corrected > 100 and result.resets == 1


def test_a_tampered_export_is_caught_and_every_differing_scan_named(matiec):
    """The comparison can fail: an export whose TON1 preset is 1.1 s instead of 2.1 s
    differs from the engine at the scans the timer's output differs, all counted."""
    valve = load_project(PROJECTS / "cispi_valve")
    tampered = shorter_ton1(write_st(build(valve)))
    with pytest.raises(AssertionError, match=r"^\d+ of 501 scans differ; the first: scan \d+ "
                       r"\(t = \d+ us\): TON1 = 1, engine 0"):
        MatiecTwin(valve, text=tampered).run(engine_for(valve), 5_000_000)
