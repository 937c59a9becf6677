"""z3 proves that exported blocks, as blark parses them, are the scan program's (the
statements the engine runs, hmi.program): each stopwatch monitor FB (hmi.program.monitors)
for every input and every state with its phase one of the three, the memory FB (the timers
and observers: hmi.program.timers, hmi.program.memories) for every input and every state, and
each diagnoser FB (hmi.program.diagnosers, in each of its modes, and its fault reset) for
every input and every state naming a state, and the control FB (the GRAFCET's step times,
evolution and actions, the equations: hmi.program.grafcet, hmi.program.memories, and the
first call's reset) for every input and every reachable state (tests/ir_prove.py says how
and what corresponds); tampered blocks are refuted with a counterexample."""

from __future__ import annotations

import time

import pytest

from hmi.export.build import build
from hmi.export.st import write_st
from hmi.project.diagnosers import diagnosers_of
from hmi.project.loader import load_project
from hmi.project.monitors import monitors_of
from tests.conftest import PROJECTS
from tests.ir_prove import prove_control, prove_diagnoser, prove_memory, prove_monitor

NAMES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())


def _export(name: str):
    project = load_project(PROJECTS / name)
    return project, write_st(build(project))


def _replacing(old: str | None, new: str | None):
    """The tampering of a block: its first `old` replaced by `new` (None: the block as
    exported); `old` must be there, or the test would prove the untouched block."""
    def tamper(fb: str) -> str:
        if old is None or new is None:
            return fb
        assert old in fb
        return fb.replace(old, new, 1)
    return tamper


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

    proofs = prove_monitor(project, text, "conveyor", _replacing(old, new))
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

    proofs = prove_memory(project, text, _replacing(old, new))
    assert len(proofs) == 7
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_every_exported_diagnoser_is_the_programs_for_every_input_and_state(name):
    project, text = _export(name)
    failed = []
    for spec in diagnosers_of(project):
        start = time.process_time()
        proofs = prove_diagnoser(project, text, spec.name)
        hld = any(h.diagnoser == spec.name for h in project.high_level)
        flags = sum(1 + bool(p.filtered) for p in spec.partitions)
        # 6 of a scan, one per flag or route, the refinement, 3 of a reset, invariant, bounds
        assert len(proofs) == 6 + flags + hld + 3 + 2
        failed += [f"{spec.name}: {p.name}: {p.detail}" for p in proofs if not p.proved]
        print(f"\n{name}: diagnoser {spec.name}, {len(proofs)} properties, "
              f"{time.process_time() - start:.0f} s CPU")
    assert not failed, "\n".join(failed)


_STATE = {"a scan: the state", "a scan: the decision's labels and Faulty"}
_FLAGS = {f"a scan: {f}: the value written (flag or route)" for f in ("def_fsc", "def_fso",
                                                                      "def_V")}
_SLOW_CHANGE = pytest.mark.slow  # (each change costs a parse of the block: ~12 s CPU)


# The valve's diagnoser V1 (36 states): each change refuted on what it breaks.
@pytest.mark.parametrize(("old", "new", "refuted"), [
    (None, None, set()),
    # a faulty state's clock moved on by the whole gap, not the gap less one period
    ("Since := Since + (L_delta - Period);", "Since := Since + L_delta;",
     _STATE | _FLAGS | {"a scan: the time the state was entered"}),
    # a step of exactly 10 periods read as a gap
    ("IF (Scan <> (L_ls + 1)) OR (L_delta > Gap) THEN",
     "IF (Scan <> (L_ls + 1)) OR (L_delta >= Gap) THEN",
     _STATE | _FLAGS | {"a scan: the time the state was entered"}),
    # a window [0, 300 ms) closed at 300 ms
    ("IF (L_t < T#300ms) AND NOT fsc AND NOT fso THEN",
     "IF (L_t <= T#300ms) AND NOT fsc AND NOT fso THEN",
     _STATE | _FLAGS - {"a scan: def_fso: the value written (flag or route)"}),
    # a label forgotten in one state (B1A holds F7)
    ("F7 := (State = 13) OR (State = 21) OR (State = 27) OR (State = 30);",
     "F7 := (State = 13) OR (State = 21) OR (State = 27);",
     {"a scan: the decision's labels and Faulty"}),
    pytest.param(  # a timeout into the wrong state
        "(* N2 -> B2 after 300ms *)\n                        State := 10;",
        "(* N2 -> B2 after 300ms *)\n                        State := 11;",
        _STATE | _FLAGS - {"a scan: def_V: the value written (flag or route)"},
        marks=_SLOW_CHANGE),
    pytest.param(  # a fault reset whose flags never follow
        "        Dirty := TRUE;\n    END_IF;\nELSE", "    END_IF;\nELSE",
        {"a fault reset: the flags follow at the next scan (not when off)"},
        marks=_SLOW_CHANGE),
    pytest.param(  # a resync rule that forgets a condition
        "ELSIF fso AND NOT fsc AND NOT C AND NOT O THEN\n                (* resync rule 2",
        "ELSIF fso AND NOT C AND NOT O THEN\n                (* resync rule 2",
        {"a fault reset: re-synchronised by the first resync rule that holds"},
        marks=_SLOW_CHANGE),
    pytest.param(  # observe read as FTC: the sensors reconstructed
        "CASE Mode OF\n        1:", "CASE Mode OF\n        3:",
        {"a scan: fsc_filter: the value written (flag or route)",
         "a scan: fso_filter: the value written (flag or route)"},
        marks=_SLOW_CHANGE),
])
def test_the_valves_diagnoser_is_proved_and_a_wrong_one_refuted(old, new, refuted):
    project, text = _export("cispi_valve")

    proofs = prove_diagnoser(project, text, "V1", _replacing(old, new))
    assert len(proofs) == 16
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)


# The subsystem's V2 with its High Level Diagnoser (the decision {F1, F13} refined).
@pytest.mark.slow
@pytest.mark.parametrize(("old", "new", "refuted"), [
    ("RefinedTo := 13;", "RefinedTo := 12;",
     {"a scan: the High Level Diagnoser's refinement (Refined, RefinedTo, Armed)",
      "a scan: the decision's labels and Faulty"}),
    # armed again once refined
    ("Armed := NOT Refined AND (State = 15);", "Armed := (State = 15);",
     {"a scan: the High Level Diagnoser's refinement (Refined, RefinedTo, Armed)"}),
])
def test_a_wrong_refinement_is_refuted(old, new, refuted):
    project, text = _export("cispi_subsystem")

    proofs = prove_diagnoser(project, text, "V2", _replacing(old, new))
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_the_exported_control_is_the_programs_for_every_input_and_reachable_state(name):
    project, text = _export(name)
    start = time.process_time()
    proofs = prove_control(project, text)
    print(f"\n{name}: control, {len(proofs)} properties, {time.process_time() - start:.1f} s "
          "CPU")
    grafcet = project.control(None).grafcet
    steps = len(grafcet.steps) if grafcet is not None else 0
    # outputs, memories, steps and their times, their activation, the history; the
    # globals not written, the invariant, the bounds
    assert len(proofs) >= len(project.outputs) + 3 * steps + 3
    failed = [f"{p.name}: {p.detail}" for p in proofs if not p.proved]
    assert not failed, "\n".join(failed)


_SITUATIONS = ("a call keeps the reachable states (inactive steps' times 0; started; the "
               "active steps one of 4 situations)")
_X0_FIRED = {"O: its value after the call", "X0.t: its value after the call",
             "X0: active with its activation time, or inactive", "X0: its value after the call",
             "X1: active with its activation time, or inactive", "X1: its value after the call"}


# The valve's GRAFCET (X0 -> X1 -> X2 -> X3 -> X0): each change refuted on what it breaks,
# or proved equivalent for every reachable state.
@pytest.mark.parametrize(("old", "new", "refuted"), [
    (None, None, set()),
    # a receptivity's step time read with > (X0 left one scan late at exactly 1 s)
    ("IF X0 AND fsc_filter AND (X0_t >= T#1s) THEN",
     "IF X0 AND fsc_filter AND (X0_t > T#1s) THEN", _X0_FIRED),
    # the first call without the initial step's activation time
    ("    Started := TRUE;\n    X0_since := Now;\n", "    Started := TRUE;\n", _X0_FIRED),
    # the first call never remembered: the GRAFCET reset at every call
    ("    Started := TRUE;\n", "", {_SITUATIONS}),
    # a deactivated step keeping its time
    ("        X3 := FALSE;\n        X3_t := T#0ms;\n", "        X3 := FALSE;\n",
     {"X3.t: its value after the call", _SITUATIONS}),
    # an activation time 1 ms early
    ("        X1_since := Now;", "        X1_since := Now - T#1ms;",
     {"X1: active with its activation time, or inactive"}),
    # a continuous action on the wrong step
    ("IF X3 THEN\n    FOV_C := TRUE;", "IF X2 THEN\n    FOV_C := TRUE;",
     {"C: its value after the call"}),
    # equivalent: O is driven by a continuous action, its previous order never read
    ("FOV_O := O;", "FOV_O := FALSE;", set()),
    # equivalent in every reachable situation: X0 and X3 are never active together, so
    # rule 5 (a step deactivated and activated stays active) is not needed for X0
    ("IF L_fire_0 AND NOT L_fire_3 THEN", "IF L_fire_0 THEN", set()),
])
def test_the_valves_control_is_proved_and_a_wrong_one_refuted(old, new, refuted):
    project, text = _export("cispi_valve")

    proofs = prove_control(project, text, _replacing(old, new))
    assert len(proofs) == 17
    assert {p.name for p in proofs if not p.proved} == refuted
    assert all("counterexample" in p.detail for p in proofs if not p.proved)


def test_the_controls_own_history_is_proved():
    """The palletizer's law reads prev(X7), a step of its own: the block keeps it; not
    shifting it at the end of the call is refuted."""
    project, text = _export("palletizer")
    assert all(p.proved for p in prove_control(project, text))
    old = "(* this block's values back in time *)\nprev_X7 := X7;\n"
    proofs = prove_control(project, text, lambda fb: fb.replace(old, "", 1))
    assert {p.name for p in proofs if not p.proved} == {"prev_X7: the value 1 scan(s) back"}
