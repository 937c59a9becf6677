"""Mutation testing of the exported Structured Text (tests/st_mutants.py): every single-operator
change to an exported POU body must be caught by the agreement with the engine on recorded
traces, or be judged by z3 (a survivor in the filter or in a stopwatch monitor: proved
equivalent to the engine's, or refuted with a counterexample, which catches it), or be listed
below with the reason, as an equivalent mutant or a gap in the traces (what no trace reaches):
an honest list, not a skip.

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
from tests.ir_prove import prove_monitor
from tests.st_mutants import RandomRun, judge, mutants, record, replay, sample, study_runs
from tests.st_prove import Unsupported, indices_not_negative, prove_filter

# Survivors of the whole study that are equivalent mutants, outside the blocks z3 judges: the
# block computes the same values whatever the inputs and state (checked by hand). Keyed by
# Mutant.key().
# What the study compares is what the engine holds (outputs, FOV, violations, latch,
# timers, observers, flags, diagnosers, monitors): a step's time is the control FB's own.
_UNREAD_STEP_TIME = ("a step time no receptivity, action or equation reads (only X1.t is "
                     "read): not a value of the cell")
_X1_T_RESET = ("X1.t is computed again (Now - X1_since) at the start of the next scan, "
               "before anything reads it")
_FTC = "Ftc := (DiagnosisMode <> 1) AND (DiagnosisMode <> 2),"
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
    },
}

# How many of the filter's survivors z3 leaves unproved; a new one fails.
FILTER_UNPROVED = {"conveyor_robot": 0}

# Survivors that are gaps in the traces, not equivalent mutants: what no recorded trace
# reaches. Listed so that a new survivor fails the study and these stay in sight.
GAPS: dict[str, dict[str, str]] = {"conveyor_robot": {}}

# Survivors of the traces that a test of their own catches (the test named).
CAUGHT_BY_TESTS: dict[str, dict[str, str]] = {
    "conveyor_robot": {
        "PRG_conveyor_robot_Safety: Clock(IN := TRUE, PT := T#24d); "
        "[T#24d -> T#2073600001ms]": (
            "tests/test_export.py::test_the_programs_clock_saturates_at_24_days: the clock "
            "read at 24 days and 1 ms (no recorded trace runs 24 days)"),
    },
}


def _proved_equivalent(name: str, text: str) -> bool:
    """A mutated filter FB proved equal to the engine's filter by z3 (tests/st_prove.py): an
    equivalent mutant, not a gap in the traces. First for every input and state; when a
    loop of the mutant then runs more than 100 times (the block's own run at most 4 times
    here: e.g. a next-subset step that counts up a Comb element left from an earlier call,
    which "every state" lets hold any negative number), for every state where the kept index
    lists hold no negative value, an invariant the proof shows the mutant keeps (they start
    at 0 on a PLC): every state the PLC reaches."""
    project = load_project(PROJECTS / name)
    limit = max_distance(source.filter_bound(project))
    try:
        return all(p.proved for p in prove_filter(project, text, limit, loop_limit=100))
    except Unsupported:
        pass
    try:
        return all(p.proved for p in prove_filter(project, text, limit, loop_limit=100,
                                                  invariant=indices_not_negative,
                                                  unchecked=2))
    except Unsupported:
        return False


def _monitor_judged(name: str, text: str, pou: str) -> bool | None:
    """A mutated stopwatch monitor FB against the scan program's monitor (tests/ir_prove.py):
    True proved equivalent, False refuted (a counterexample: the mutant is caught), None
    when z3 or the executor cannot say."""
    project = load_project(PROJECTS / name)
    try:
        proofs = prove_monitor(project, text, pou.split("_Mon_", 1)[1])
    except Unsupported:
        return None
    if any(not p.proved and "counterexample" in p.detail for p in proofs):
        return False
    return True if all(p.proved for p in proofs) else None


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
                   or CAUGHT_BY_TESTS.get(name, {}).get(v.mutant.key())
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
    # a survivor in the filter FB: z3 proves it equivalent; in a monitor FB: z3 proves it
    # equivalent or refutes it; elsewhere: listed, with the reason (an equivalent mutant, or a
    # gap in the traces)
    unexplained, proved, gaps, refuted, tested = [], 0, 0, 0, 0
    unproved = []
    for v in verdicts:
        if v.outcome != "survived":
            continue
        if "_Mon_" in v.mutant.pou:
            judged = _monitor_judged(name, v.mutant.apply(rec.text), v.mutant.pou)
            if judged is None:
                unexplained.append(v.mutant.key())
            proved += judged is True
            refuted += judged is False
        elif v.mutant.pou.endswith("_Filter"):
            if _proved_equivalent(name, v.mutant.apply(rec.text)):
                proved += 1
            else:
                unproved.append(v.mutant.describe())
        elif v.mutant.key() in CAUGHT_BY_TESTS[name]:
            tested += 1
        elif v.mutant.key() in GAPS[name]:
            gaps += 1
        elif v.mutant.key() not in EQUIVALENT[name]:
            unexplained.append(v.mutant.key())
    print(f"  {proved} survivors proved equivalent by z3, {refuted} refuted by z3 (caught), "
          f"{tested} caught by a test of their own, {gaps} gaps in the traces")
    # the filter survivors z3 does not prove equal: printed, held to FILTER_UNPROVED
    print("  filter survivors not proved equivalent: " + "; ".join(unproved))
    assert len(unproved) <= FILTER_UNPROVED[name], unproved
    assert unexplained == []
