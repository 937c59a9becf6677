"""The sorting and palletizer projects as a whole: they check clean, their functional
programs do the work safely under the corrector, their faulty programs are kept safe by it and
do damage without it, and the fault scenarios of docs/sorting.md and docs/palletizer.md give
the results written there."""

from __future__ import annotations

from functools import cache

import pytest

from hmi.bench import sections
from hmi.bench.cellrun import CellRun, measure, report_lines
from hmi.cli import main
from hmi.project.loader import load_project
from hmi.project.scenarios import scenarios_of
from tests.cellruns import SHARED, scenario_run
from tests.conftest import PROJECTS

S = 1_000_000


@cache
def cell(name: str, control: str = "normal", policy: str = "correct", seconds: int = 60,
         inject: tuple[str, ...] = ()) -> CellRun:
    return measure(load_project(PROJECTS / name), control, seconds * S, policy=policy,
                   timed=False, inject=inject)


def sorted_boxes(run: CellRun) -> int:
    return run.counters["sorted_left"] + run.counters["sorted_right"]


@pytest.mark.parametrize("name", ["sorting", "palletizer"])
def test_check_passes_with_no_conflict_and_always_a_safe_vector(name, capsys):
    assert main(["check", str(PROJECTS / name)]) == 0
    out = capsys.readouterr().out
    assert "conflicts between simple constraints: none" in out
    assert "situations with no safe output vector: none" in out
    assert "Warnings" not in out
    assert out.rstrip().endswith("OK: the project is valid")


# -- sorting ---------------------------------------------------------------------------------

def test_sorting_functional_program_sorts_safely_within_distance_2():
    run = cell("sorting", seconds=60)
    assert sorted_boxes(run) >= 9
    assert run.counters["missorted"] == 0 and run.counters["lost"] == 0
    assert not run.damage and run.unsafe_written == 0 and run.fallbacks == 0
    assert run.violated_scans > 0  # the program relies on the filter for the entry conveyor
    assert run.max_distance <= 2  # 004 §5.3


def test_sorting_functional_program_alone_drives_boxes_into_the_turned_table():
    run = cell("sorting", policy="monitor", seconds=20)
    assert run.damage["box_against_table"] >= 1
    assert run.unsafe_written > 0


def test_sorting_faulty_program_is_kept_safe_by_the_corrector():
    run = cell("sorting", control="faulty", seconds=60)
    assert not run.damage and run.unsafe_written == 0 and run.fallbacks == 0
    assert run.corrected_scans > 5000
    assert run.max_distance == 2
    assert sorted_boxes(run) >= 5 and run.counters["missorted"] == 0


def test_sorting_faulty_program_does_damage_under_monitor():
    run = cell("sorting", control="faulty", policy="monitor", seconds=20)
    assert {"box_sheared", "turn_overrun", "rollers_both_ways"} <= set(run.damage)


def test_sorting_faulty_program_under_block_is_latched_safe():
    run = cell("sorting", control="faulty", policy="block", seconds=15)
    assert not run.damage and sorted_boxes(run) == 0


# -- palletizer ------------------------------------------------------------------------------

def test_palletizer_functional_program_builds_pallets_safely():
    run = cell("palletizer", seconds=80)
    assert run.counters["pallets"] >= 1 and run.counters["layers"] >= 4
    assert run.counters["lost"] == 0
    assert not run.damage and run.unsafe_written == 0 and run.fallbacks == 0
    assert run.max_distance <= 2


def test_palletizer_faulty_program_is_kept_safe_by_the_corrector():
    run = cell("palletizer", control="faulty", seconds=80)
    assert not run.damage and run.unsafe_written == 0 and run.fallbacks == 0
    assert run.counters["pallets"] >= 1 and run.counters["lost"] == 0
    assert run.max_distance == 2


def test_palletizer_faulty_program_does_damage_under_monitor():
    run = cell("palletizer", control="faulty", policy="monitor", seconds=60)
    assert {"pusher_both_ways", "box_dropped", "layer_dropped", "load_crushed",
            "box_against_pusher"} <= set(run.damage)


# -- fault scenarios (docs/sorting.md, docs/palletizer.md) -------------------------------------

# The damage each scenario of the projects' scenarios.yaml must (or must not) do, as the doc
# pages report it; every scenario a project declares must be listed here, and only those.
EXPECTED_DAMAGE = {
    ("sorting", "tt_back_stuck1"): set(),
    ("sorting", "entry_end_stuck0"): set(),
    ("sorting", "high_stuck0"): set(),
    ("sorting", "left_blocked"): set(),
    ("sorting", "tt_back_stuck0"): {"box_sheared"},
    ("sorting", "tt_front_stuck0"): {"box_dropped"},
    ("sorting", "table_jam"): {"turn_stall"},
    ("palletizer", "plate_closed_stuck1"): set(),
    ("palletizer", "clamp_closed_stuck1"): set(),
    ("palletizer", "layer_eye_stuck0"): {"load_crushed"},
    ("palletizer", "pusher_home_stuck1"): {"box_against_pusher"},
    ("palletizer", "clamp_open_stuck1"): {"plate_into_layer"},
    ("palletizer", "elevator_jam"): {"elevator_stall"},
}


def test_every_declared_scenario_has_its_expected_outcome():
    declared = {(name, s.name) for name in ("sorting", "palletizer")
                for s in scenarios_of(load_project(PROJECTS / name))}
    assert declared == set(EXPECTED_DAMAGE)


@SHARED
@pytest.mark.parametrize("name,scenario", sorted(EXPECTED_DAMAGE),
                         ids=[f"{n}-{s}" for n, s in sorted(EXPECTED_DAMAGE)])
def test_fault_scenarios(name, scenario):
    run = scenario_run(name, scenario)
    assert set(run.damage_kinds) == EXPECTED_DAMAGE[(name, scenario)]
    assert len(run.damage) <= 1  # one event at most: the cell stops, or goes on safely
    assert run.unsafe_written == 0  # whatever the plant does, the filter never writes unsafe


@SHARED
def test_scenario_details():
    # A stuck high sensor sends high boxes left: missorted, not damage.
    assert scenario_run("sorting", "high_stuck0").counters["missorted"] == 2
    # The plate's reconstruction lets the palletizer work on with a stuck plate_closed switch.
    run = scenario_run("palletizer", "plate_closed_stuck1")
    assert run.counters["pallets"] == 1 and run.counters["layers"] == 5
    assert run.counters["lost"] == 0


# -- commands ------------------------------------------------------------------------------------

def test_run_command_reports_the_cells_work_and_injections(capsys):
    code = main(["run", str(PROJECTS / "sorting"), "--for", "20s", "--inject",
                 "tt_back_stuck1@15s"])
    out = capsys.readouterr().out
    assert code == 0
    assert "Plant: arrived 4, sorted_left 0, sorted_right 2" in out
    assert "Faults injected: tt_back_stuck1@15s" in out


def test_an_unknown_fault_names_what_the_cell_can_simulate(capsys):
    assert main(["run", str(PROJECTS / "palletizer"), "--for", "1s", "--inject",
                 "clamp_stuck@1s"]) == 2
    err = capsys.readouterr().err
    assert "unknown fault clamp_stuck@1s" in err and "clamp_jam" in err
    assert "Traceback" not in err


def test_bench_sections_exist_and_report(capsys):
    assert {"sorting", "palletizer"} <= set(sections())
    run = measure(load_project(PROJECTS / "sorting"), "faulty", 10 * S)
    lines = report_lines(run, "work")
    assert lines[2].startswith("    Hamming distance: max 1; histogram 0: ")
    assert lines[3].startswith("    combined search (") and "p99" in lines[3]
    assert lines[4].startswith("    whole filter stage per scan: p50")
