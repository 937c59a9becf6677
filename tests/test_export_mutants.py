"""Mutation testing of the exported Structured Text (tests/st_mutants.py): every single-operator
change to an exported POU body must be caught by the agreement with the engine on recorded
traces, or be shown equivalent (a filter survivor by z3, the others listed below with the
reason), or be listed as a gap in the traces (what no trace reaches): an honest list, not a
skip.

The traces (tests/st_mutants.py, study_runs): each project's scenarios (export_traces
without the fault campaign, nor the faulty program's runs, which are another export), and
eight seeded runs on a plant of random inputs, with policy switches and fault resets: three
with the project's control law, three in manual mode with random requests (RandomRun: the
corrector meets vectors no control law writes; the control FB is replaced by the requests
there), two with slow input changes (a task runs for seconds: the monitors' verdicts).
"""

from __future__ import annotations

from collections import Counter

import pytest

from hmi.export import source
from hmi.export.filter_pou import max_distance
from hmi.project.loader import load_project
from tests.conftest import PROJECTS
from tests.export_harness import export_traces
from tests.st_mutants import RandomRun, judge, mutants, record, replay, sample, study_runs
from tests.st_prove import Unsupported, prove_filter

# Survivors of the whole study that are equivalent mutants: the block computes the same
# values whatever the inputs and state (checked by hand; the filter's are also proved
# equivalent by z3, tests/test_export_prove.py). Keyed by Mutant.describe().
# What the study compares is what the engine holds (outputs, FOV, violations, latch,
# timers, observers, flags, diagnosers, monitors): a step's time is the control FB's own.
_UNREAD_STEP_TIME = ("a step time no receptivity, action or equation reads (only X1.t is "
                     "read): not a value of the cell")
_X1_T_RESET = ("X1.t is computed again (Now - X1_since) at the start of the next scan, "
               "before anything reads it")
_FTC = "Ftc := (DiagnosisMode <> 1) AND (DiagnosisMode <> 2),"
_ARMED = ("Armed is the plain watchdog kept beside the monitor only to measure its lead "
          "(docs/monitors.md): not a value the engine's monitor decides with, not compared")
_RULE = ("a released fault's Rule: the evidence is compared only while the monitor holds a "
         "fault, and the next fault sets it")
EQUIVALENT: dict[str, dict[str, str]] = {
    "conveyor_robot": {
        "FB_conveyor_robot_Control: IF NOT Started THEN [NOT -> (dropped)]": (
            "the first-call block then never runs; it would set the initial steps' "
            "activation times to Now, which is T#0ms at the first call (the program's clock "
            "starts there), their default; the initial steps store no action"),
        "FB_conveyor_robot_Control: Started := TRUE; [TRUE -> FALSE]": (
            "the first-call block runs at every call: it sets X3_since and X10_since to Now, "
            "so X3.t and X10.t read 0, which nothing reads; the initial steps store no "
            "action"),
        **{f"FB_conveyor_robot_Control: X{n}_t := Now - X{n}_since; [- -> +]": _UNREAD_STEP_TIME
           for n in (3, 10, 2, 11, 12)},
        **{f"FB_conveyor_robot_Control: X{n}_t := T#0ms; [T#0ms -> T#1ms]": _UNREAD_STEP_TIME
           for n in (3, 10, 2, 11, 12)},
        "FB_conveyor_robot_Control: X1_t := T#0ms; [T#0ms -> T#1ms]": _X1_T_RESET,
        **{f"PRG_conveyor_robot_Safety: {_FTC} [{old} -> {new}]": (
            "Ftc gates the masks of the diagnosers' actuator partitions; the cell has no "
            "diagnoser, so the filter never reads it")
           for old, new in (("<>", "="), ("1", "0"), ("AND", "OR"), ("2", "1"))},
        **{f"FB_conveyor_robot_Mon_{m}: {line} [{old} -> {new}]": _ARMED
           for m in ("conveyor", "robot")
           for line, old, new in (("Armed := TRUE;", "TRUE", "FALSE"),
                                  ("Armed := FALSE;", "FALSE", "TRUE"))},
        **{f"FB_conveyor_robot_Mon_{m}: IF Armed AND (L_x >= T#{t}s) THEN [{old} -> {new}]":
           _ARMED for m, t in (("conveyor", 5), ("robot", 4))
           for old, new in (("AND", "OR"), (">=", ">"), (f"T#{t}s", f"T#{t}001ms"))},
        **{f"FB_conveyor_robot_Mon_{m}: Rule := 0; [0 -> 1]": _RULE
           for m in ("conveyor", "robot")},
    },
}

_END = ("an end verdict (late_end, overrun, too_fast) needs its bound crossed at the very scan "
        "the task ends (while it runs, the running verdicts fire first): no trace does")
_BOUND = ("a running verdict's bound met exactly (y = alpha or beta at the scan x reaches "
          "gamma, ...): no trace meets it")
_PHASE = ("the phase just set is read only by `y = beta AND p = 1`, a bound no trace meets")


def _monitor_gaps(m: str, alpha: int, beta: int, gamma: int) -> dict[str, str]:
    a, b, g = (f"T#{v}s" for v in (alpha, beta, gamma))
    m1 = {v: f"T#{v[2:-1]}001ms" for v in (a, b, g)}
    pou = f"FB_conveyor_robot_Mon_{m}"
    out = {}
    for line, changes, why in (
            (f"IF L_x >= {g} THEN", ((">=", ">"), (g, m1[g])), _END),
            ("L_verdict := 4;", (("4", "3"),), _END),
            (f"ELSIF L_y > {b} THEN", ((">", ">="), (b, m1[b])), _END),
            ("L_verdict := 3;", (("3", "2"),), _END),
            (f"ELSIF L_y < {a} THEN", (("<", "<="), (a, m1[a])), _END),
            ("L_p := 2;", (("2", "1"),), _PHASE),
            ("L_p := 1;", (("1", "0"),), _PHASE),
            (f"IF (L_y < {a}) AND ((L_x + ({a} - L_y)) >= {g}) THEN", (("<", "<="), (a, m1[a])),
             _BOUND),
            (f"ELSIF (L_y >= {a}) AND (L_x >= {g}) THEN", ((">=", ">"), (a, m1[a])), _BOUND),
            (f"ELSIF (L_y > {b}) OR ((L_y = {b}) AND (L_p = 1)) THEN", ((">", ">="), (b, m1[b])),
             _BOUND)):
        for old, new in changes:
            out[f"{pou}: {line} [{old} -> {new}]"] = why
    return out


# How many of the filter's survivors z3 leaves unproved (above: why); a new one fails. The
# conveyor's three are the k-subset enumerator's: FOR I := K - 1 -> K - 0 in the next-subset
# step (its WHILE runs past the executor's 100 passes), and two that let the search write
# Comb[K] (FOR I := 0 TO K - 0 in the first subset, and the WHILE's first AND -> OR, which
# lets K pass N): the executor stops at the concrete index out of bounds without asking
# whether its path is feasible, so neither equivalence nor a counterexample is claimed.
FILTER_UNPROVED = {"conveyor_robot": 3}

# Survivors that are gaps in the traces, not equivalent mutants: what no recorded trace
# reaches. Listed so that a new survivor fails the study and these stay in sight.
GAPS: dict[str, dict[str, str]] = {
    "conveyor_robot": {
        **_monitor_gaps("conveyor", 3, 4, 5), **_monitor_gaps("robot", 2, 3, 4),
        "PRG_conveyor_robot_Safety: Clock(IN := TRUE, PT := T#24d); "
        "[T#24d -> T#2073600001ms]": (
            "the program's clock saturates at 24 days: one millisecond later is beyond any "
            "run a test makes"),
    },
}


def _proved_equivalent(name: str, text: str) -> bool:
    """A mutated filter FB proved equal to the engine's filter by z3, for every input and
    state (tests/st_prove.py): an equivalent mutant, not a gap in the traces. A loop the
    mutant leaves running more than 100 times (the block's own run at most 4 times here) is
    not proved: e.g. a k-subset enumerator that reads a Comb element left from an earlier
    call, which "every state" lets hold anything."""
    project = load_project(PROJECTS / name)
    limit = max_distance(source.filter_bound(project))
    try:
        return all(p.proved for p in prove_filter(project, text, limit, loop_limit=100))
    except Unsupported:
        return False


def _study(name: str, runs, k: int | None = None, seed: int = 0):
    rec, traces = record(name, runs)
    found = mutants(rec.text)
    chosen = found if k is None else sample(found, k, seed)
    return rec, traces, found, [judge(rec, traces, m) for m in chosen]


def _report(name: str, found, verdicts) -> tuple[Counter, list[str]]:
    counts = Counter(v.outcome for v in verdicts)
    survivors = [v.mutant.describe() for v in verdicts if v.outcome == "survived"]
    print(f"\n{name}: {len(found)} mutants, {len(verdicts)} judged: {counts['caught']} caught, "
          f"{counts['survived']} survived, {counts['stillborn']} stillborn")
    for v in verdicts:
        if v.outcome == "survived":
            why = (EQUIVALENT.get(name, {}).get(v.mutant.key())
                   or GAPS.get(name, {}).get(v.mutant.key(), "not listed"))
            print(f"  survived: {v.mutant.describe()}  ({why})")
    return counts, survivors


def test_the_mutants_cover_each_operator_and_only_bodies():
    rec, _traces = record("conveyor_robot", [RandomRun(1, scans=10)])
    found = mutants(rec.text)
    kinds = Counter((m.old.upper(), m.new.upper()) for m in found
                    if not m.old[0].isdigit() and "#" not in m.old)
    for pair in [("AND", "OR"), ("OR", "AND"), ("NOT", ""), ("<", "<="), (">=", ">"),
                 ("=", "<>"), ("<>", "="), ("+", "-"), ("-", "+"), ("TRUE", "FALSE"),
                 ("FALSE", "TRUE")]:
        assert kinds[pair], pair
    assert any(m.old.startswith("T#") for m in found)  # a TIME literal one ms longer
    assert any(m.old.isdigit() for m in found)  # an integer moved by one
    lines = rec.text.splitlines()
    # never a declaration (VAR ... END_VAR) nor the configuration
    assert not any(":" in lines[m.line - 1].split(":=")[0] and " : " in lines[m.line - 1]
                   for m in found)
    assert max(m.line for m in found) < next(k for k, line in enumerate(lines, 1)
                                             if line.startswith("CONFIGURATION"))


def test_the_unmutated_export_replays_its_recording_and_a_mutant_does_not():
    runs = [*export_traces("conveyor_robot", scenarios=("nominal",))[:1],
            RandomRun(11, 400, True)]
    rec, traces = record("conveyor_robot", runs)
    assert replay(rec, traces, rec.text)[0] is None
    context = "IF B THEN\n        Act := Act OR"  # push_onto_waiting_pallet's: B
    wrong = rec.text.replace(context, context.replace("IF B", "IF NOT B"), 1)
    assert wrong != rec.text
    found, ran = replay(rec, traces, wrong)
    # the nominal run never has B with d (a pallet pushed onto one waiting): the random
    # requests do, and the filter then writes a different d
    assert found is not None and found.startswith("random manual seed 11, scan ")
    assert ran < 1201 + 400


def test_a_sample_of_mutants_is_caught_every_day():
    """A bounded sample of the conveyor/robot cell's mutants on short traces (the whole
    study is the slow test below)."""
    runs = [*export_traces("conveyor_robot")[:2], RandomRun(1, 600),
            RandomRun(11, 600, manual=True)]
    _rec, _traces, found, verdicts = _study("conveyor_robot", runs, k=40, seed=5)
    counts, _survivors = _report("conveyor_robot (sample)", found, verdicts)
    # (2,400 scans: the short traces leave boundary and corrector mutants alive, which the
    # whole study's traces catch)
    assert counts["caught"] >= 25


@pytest.mark.slow
def test_every_mutant_of_the_conveyor_robot_export_is_caught_or_equivalent():
    name = "conveyor_robot"
    rec, _traces, found, verdicts = _study(name, study_runs(name))
    counts, _survivors = _report(name, found, verdicts)
    assert counts["caught"] + counts["survived"] + counts["stillborn"] == len(found)
    # a survivor in the filter FB: z3 proves it equivalent; elsewhere: listed, with the reason
    # (an equivalent mutant, or a gap in the traces)
    unexplained, proved, gaps = [], 0, 0
    unproved = []
    for v in verdicts:
        if v.outcome != "survived":
            continue
        if v.mutant.pou.endswith("_Filter"):
            if _proved_equivalent(name, v.mutant.apply(rec.text)):
                proved += 1
            else:
                unproved.append(v.mutant.describe())
        elif v.mutant.key() in GAPS[name]:
            gaps += 1
        elif v.mutant.key() not in EQUIVALENT[name]:
            unexplained.append(v.mutant.key())
    print(f"  {proved} filter survivors proved equivalent by z3, {gaps} gaps in the traces")
    # Not yet judged: the filter survivors z3 does not prove equal under "every state" (the
    # k-subset enumerator's mutants); printed, and held to the ones known (FILTER_UNPROVED)
    print("  filter survivors not proved equivalent: " + "; ".join(unproved))
    assert len(unproved) <= FILTER_UNPROVED[name], unproved
    assert unexplained == []
