"""The CISPI subsystem (000 §3.3) as a whole: it checks clean, its normal program fills T2
cycle after cycle without needing the filter, its faulty program is kept safe by the filter,
each valve is diagnosed by its own instance of the valve component, and the scenarios and
campaign runs quoted in docs/cispi_subsystem.md give the results written there."""

from __future__ import annotations

from functools import cache

import pytest

from hmi.bench.cellrun import CellRun, measure
from hmi.cli import main
from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.project.model import CampaignScenario
from hmi.project.scenarios import find_scenario
from hmi.studies.campaign import CONFIGS, run_one
from tests.conftest import PROJECTS

S = 1_000_000
SUBSYSTEM = PROJECTS / "cispi_subsystem"


@cache
def project():
    return load_project(SUBSYSTEM)


@cache
def cell(control: str = "normal", policy: str = "correct", seconds: int = 80,
         inject: tuple[str, ...] = ()) -> CellRun:
    return measure(project(), control, seconds * S, policy=policy, timed=False, inject=inject)


def test_check_passes_with_both_valve_instances_and_no_warning(capsys):
    assert main(["check", str(SUBSYSTEM)]) == 0
    out = capsys.readouterr().out
    assert "Components (2 instances)" in out
    assert "Safety constraints (19: 15 simple, 4 combined)" in out
    assert "conflicts between simple constraints: none" in out
    assert "situations with no safe output vector: none" in out
    assert out.count("DC read from the diagram = 10/13 = 76.9 %") == 2  # one per valve
    assert "Warnings" not in out
    assert out.rstrip().endswith("OK: the project is valid")


def test_the_valve_parts_come_from_the_component_not_from_the_project():
    p = project()
    assert {d.name for d in p.diagnosers} == {"V1", "V2"}
    assert all(d.pos.file.endswith("components/valve.yaml") for d in p.diagnosers)
    own = [c.name for c in p.constraints if c.pos.file.endswith("constraints.yaml")]
    assert own == ["CSs1", "CSs2", "CSs3", "CSc1", "CSc2"]
    assert sum(c.name.startswith(("V1_", "V2_")) for c in p.constraints) == 14


# -- the programs ----------------------------------------------------------------------------


def test_the_normal_program_fills_t2_every_cycle_without_needing_the_filter():
    run = cell()
    assert run.counters["T2.fills"] == 4 and run.counters["P.starts"] == 5
    assert run.counters["V1.cycles"] == 4 and run.counters["V2.cycles"] == 4
    assert not run.damage and run.violated_scans == 0 and run.unsafe_written == 0


def test_the_normal_program_alone_is_safe_too():
    run = cell(policy="monitor")
    assert not run.damage and run.violated_scans == 0


def test_the_faulty_program_is_kept_safe_by_the_corrector():
    run = cell(control="faulty")
    assert not run.damage and run.unsafe_written == 0 and run.fallbacks == 0
    assert run.corrected_scans > 3000 and run.max_distance == 2
    assert run.counters["T2.fills"] >= 4  # and it still does the work
    assert run.counters["P.starts"] <= 5  # the level locks keep the pump from chattering


def test_the_faulty_program_does_damage_without_the_filter():
    run = cell(control="faulty", policy="monitor")
    assert {"dead_head", "overflow", "end_stop_overrun"} <= set(run.damage)


def test_the_faulty_program_under_safe_blocking_is_latched_safe():
    run = cell(control="faulty", policy="block", seconds=20)
    assert not run.damage and run.counters["P.starts"] == 0


# -- each valve is diagnosed by its own instance -------------------------------------------


@pytest.mark.parametrize("faulty,healthy", [("V1", "V2"), ("V2", "V1")])
def test_each_valve_is_diagnosed_independently(faulty, healthy):
    k = faulty[1]
    plant = SimPlant(project())
    plant.inject(parse_injection(f"{faulty}.F4@20s"))  # its open switch made at closed rest
    engine = Engine(project(), plant)
    seen: set[tuple[str, str]] = set()
    for now in range(0, 60 * S + 1, 10_000):
        snap = engine.step(now)
        seen |= {(d.name, d.state) for d in snap.diagnosers if d.faulty}
    states = {d.name: d for d in snap.diagnosers}
    assert (states[faulty].state, states[faulty].labels) == ("S4", ("F4",))
    assert not any(name == healthy for name, _ in seen)  # never suspected
    values = dict(zip(snap.layout.names, snap.values, strict=False))
    assert values[f"def_{faulty}_fso"] and not values[f"def_{healthy}_fso"]
    assert snap.reconstructed == (f"fso{k}",) and snap.masked == ()
    assert not plant.damage() and dict(plant.counters())["T2.fills"] == 3


@pytest.mark.parametrize("valve", ["V1", "V2"])
def test_the_diagnoser_is_what_prevents_dead_heading_on_a_stuck_open_switch(valve):
    """Filter alone: the stuck switch says the line is open, the pump runs against two shut
    valves. Filter and diagnoser: the switch is replaced by its estimate; the cycle goes on."""
    spec = project().campaign
    scenario = CampaignScenario("F4", valve, 20 * S, "", False, spec.pos)
    by_key = {c.key: c for c in CONFIGS}
    alone = run_one(project(), spec, scenario, by_key["filter_no_diag"])
    ftc = run_one(project(), spec, scenario, by_key["ftc"])
    assert alone.outcome == "Defect" and alone.damage[0].kind == "dead_head"
    assert ftc.outcome == "Tolerant" and not ftc.damage and ftc.decision == ("F4",)


# -- the documented scenarios and campaign rows ----------------------------------------------


@pytest.mark.parametrize("name,damage,fills", [
    ("v1_fso_stuck", set(), 3),
    ("v2_fso_stuck", set(), 3),
    ("v1_jam", set(), 2),
    ("t2_high_dead", set(), 5),
    ("pump_no_start", set(), 1),
    ("pump_welded", {"dead_head"}, 3),
])
def test_each_scenario_gives_what_the_documentation_says(name, damage, fills):
    scenario = find_scenario(project(), name)
    run = cell(seconds=scenario.duration_us // S, inject=scenario.injections)
    assert set(run.damage) == damage
    assert run.counters["T2.fills"] == fills


@pytest.mark.parametrize("fault,outcomes", [
    ("T2.high_stuck0@20s", ("Defect", "Tolerant", "Tolerant")),
    ("P.welded@30s", ("Defect", "Defect", "Defect")),
    ("P.no_start@20s", ("Blocked", "Blocked", "Blocked")),
    ("V1.F3@20s", ("Defect", "Defect", "Blocked")),
    ("V1.F13@26.9s", ("Defect", "Defect", "Blocked")),
])
def test_campaign_rows_quoted_in_the_documentation(fault, outcomes):
    spec = project().campaign
    scenario = next(s for s in spec.scenarios if s.name == fault)
    assert tuple(run_one(project(), spec, scenario, c).outcome for c in CONFIGS) == outcomes
