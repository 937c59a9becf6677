"""z3 proves that exported blocks, as blark parses them, are the scan program's (the
statements the engine runs, hmi.program): each stopwatch monitor FB (hmi.program.monitors)
for every input and every state with its phase one of the three, and the memory FB (the
timers and observers: hmi.program.timers, hmi.program.memories) for every input and every
state (tests/ir_prove.py says how and what corresponds); tampered blocks are refuted with a
counterexample."""

from __future__ import annotations

import time

import pytest

from hmi.export.build import build
from hmi.export.st import write_st
from hmi.project.loader import load_project
from hmi.project.monitors import monitors_of
from tests.conftest import PROJECTS
from tests.ir_prove import prove_memory, prove_monitor

NAMES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())


def _export(name: str):
    project = load_project(PROJECTS / name)
    return project, write_st(build(project))


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_every_exported_monitor_is_the_programs_for_every_input_and_state(name):
    project, text = _export(name)
    start = time.process_time()
    failed = []
    tasks = [m.name for m in monitors_of(project)]
    for task in tasks:
        proofs = prove_monitor(project, text, task)
        assert len(proofs) == 14  # 9 of a scan, 2 of a reset, location, invariant, bounds
        failed += [f"{task}: {p.name}: {p.detail}" for p in proofs if not p.proved]
    print(f"\n{name}: {len(tasks)} monitors, {time.process_time() - start:.0f} s CPU")
    assert not failed, "\n".join(failed)


def test_the_conveyor_monitor_is_proved():
    project, text = _export("conveyor_robot")
    proofs = prove_monitor(project, text, "conveyor")
    assert [p.name for p in proofs if not p.proved] == []


# Boundary changes no recorded trace meets (the task ending at the very scan x reaches gamma,
# y meeting beta exactly, the phase read only at that bound), each refuted by the proof.
@pytest.mark.parametrize(("old", "new", "refuted"), [
    ("IF L_x >= T#5s THEN", "IF L_x > T#5s THEN",
     {"a scan: the attempt's fault", "a scan: the counts of faults and completed attempts",
      "a scan: the fault label and its evidence (rule, x, y)"}),
    ("ELSIF (L_y > T#4s) OR ((L_y = T#4s) AND (L_p = 1)) THEN",
     "ELSIF (L_y > T#4001ms) OR ((L_y = T#4s) AND (L_p = 1)) THEN",
     {"a scan: the attempt's fault", "a scan: the counts of faults and completed attempts",
      "a scan: the fault label and its evidence (rule, x, y)"}),
    ("L_verdict := 4;", "L_verdict := 3;",
     {"a scan: the fault label and its evidence (rule, x, y)"}),
    ("Armed := FALSE;", "Armed := TRUE;", {"a scan: the watchdog armed"}),
    ("Location := 3;", "Location := 2;",
     {"the location: faulty while the label holds, else the phase"}),
    ("Rule := 0;\n", "Rule := 0;\n        Phase := 0;\n",
     {"a fault reset changes nothing else"}),
])
def test_a_wrong_monitor_is_refuted_with_a_counterexample(old, new, refuted):
    project, text = _export("conveyor_robot")

    def tamper(fb: str) -> str:
        assert old in fb
        return fb.replace(old, new, 1)

    proofs = prove_monitor(project, text, "conveyor", tamper)
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)


def test_a_released_faults_rule_is_not_a_value_of_the_cell():
    """`Rule := 0` at a release read as `Rule := 1`: the evidence is compared only while the
    label holds, so the block is proved equal (the mutation study's equivalent mutant)."""
    project, text = _export("conveyor_robot")
    proofs = prove_monitor(project, text, "conveyor",
                           lambda fb: fb.replace("Rule := 0;", "Rule := 1;", 1))
    assert all(p.proved for p in proofs)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_the_exported_memory_is_the_programs_for_every_input_and_state(name):
    project, text = _export(name)
    start = time.process_time()
    proofs = prove_memory(project, text)
    print(f"\n{name}: memory, {len(proofs)} properties, {time.process_time() - start:.1f} s CPU")
    assert len(proofs) == (0 if not project.timers and not project.observers
                           else len(project.timers) * 2 + len(project.observers) + 1)
    failed = [f"{p.name}: {p.detail}" for p in proofs if not p.proved]
    assert not failed, "\n".join(failed)


# The valve's memory: its two TON (open and close orders held a full travel) and two
# observers (the estimated positions); each change refuted on what it breaks.
@pytest.mark.parametrize(("old", "new", "refuted"), [
    (None, None, set()),
    ("L_q := (Now - L_s) >= T#2s450ms;", "L_q := (Now - L_s) > T#2s450ms;",
     {"TON1: the value written", "timer TON1: its state (q, since)",
      "fso_hat: the value written"}),
    ("    TON1_none := TRUE;", "    TON1_none := FALSE;", {"timer TON1: its state (q, since)"}),
    ("        TON2_since := Now;", "        TON2_since := Now - T#1ms;",
     {"timer TON2: its state (q, since)"}),
    ("fsc_hat := NOT prev_O AND", "fsc_hat := NOT prev_C AND", {"fsc_hat: the value written"}),
    ("OR (prev_fso AND NOT prev_def_fso) OR fso_hat)", "OR (prev_fso AND NOT prev_def_fso))",
     {"fso_hat: the value written"}),
])
def test_the_valves_memory_is_proved_and_a_wrong_one_refuted(old, new, refuted):
    project, text = _export("cispi_valve")

    def tamper(fb: str) -> str:
        if old is None:
            return fb
        assert old in fb
        return fb.replace(old, new, 1)

    proofs = prove_memory(project, text, tamper)
    assert len(proofs) == 7
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)
