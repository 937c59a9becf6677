"""Mutation testing of the exported Structured Text (tests/st_mutants.py, tests/mutant_study.py):
every single-operator change to an exported POU body must be caught by the agreement with the
engine on recorded traces, or be judged by z3 (a survivor in a function block is handed to
that block's proof: proved equivalent, or refuted with a counterexample, which catches it), or
be listed in tests/mutant_study.py with the reason: an honest list, not a skip.

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

from hmi.project.loader import load_project
from tests.conftest import PROJECTS
from tests.export_harness import export_traces
from tests.mutant_study import (
    CAUGHT_BY_TESTS,
    FIRST_SCAN_TEST,
    OUTCOMES,
    Choice,
    Study,
    judge_survivor,
    run_study,
)
from tests.st_mutants import RandomRun, judge, mutants, record, replay, sample


def _study(name: str, runs, k: int | None = None, seed: int = 0):
    rec, traces = record(name, runs)
    found = mutants(rec.text)
    chosen = found if k is None else sample(found, k, seed)
    return rec, traces, found, [judge(rec, traces, m) for m in chosen]


def _report(name: str, found, verdicts) -> Counter:
    counts = Counter(v.outcome for v in verdicts)
    print(f"\n{name}: {len(found)} mutants, {len(verdicts)} judged: {counts['caught']} caught, "
          f"{counts['survived']} survived, {counts['stillborn']} stillborn")
    return counts


def _checked(study: Study) -> Counter[str]:
    """The study printed, and held to its standard: every mutant judged, none unexplained."""
    print("\n" + study.report())
    counts = study.counts()
    assert sum(counts[o] for o in OUTCOMES) == len(study.judged)
    assert study.unexplained() == []
    return counts


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
    counts = _report("conveyor_robot (sample)", found, verdicts)
    # (2,400 scans: the short traces leave boundary and corrector mutants alive, which the
    # whole study's traces catch)
    assert counts["caught"] >= 25


def test_a_survivor_in_a_block_is_judged_by_that_blocks_proof():
    """The conveyor/robot cell's control law: a step's time computed from the wrong end
    survives the traces (no receptivity reads that step's time) and prove_control refutes it
    (the program's step time differs); a survivor of the program, which no block proof
    covers, is unexplained unless listed."""
    name = "conveyor_robot"
    project = load_project(PROJECTS / name)
    rec, traces = record(name, [RandomRun(1, scans=300)])
    found = mutants(rec.text)
    step_time = next(m for m in found if m.pou.endswith("_Control") and m.old == "-"
                     and m.source.startswith("X2_t := Now - X2_since"))
    assert judge(rec, traces, step_time).outcome == "survived"
    judged = judge_survivor(name, project, rec.text, step_time)
    assert judged.outcome == "refuted" and judged.how.startswith("prove_control: "), judged
    clock = next(m for m in found if m.pou.endswith("_Safety") and m.old == "T#24d")
    assert judge_survivor(name, project, rec.text, clock).outcome == "tested"
    wiring = next(m for m in found if m.pou.endswith("_Safety") and m.old == "TRUE")
    assert judge_survivor(name, project, rec.text, wiring).outcome == "unexplained"


def test_a_logged_study_goes_on_where_it_ended(tmp_path):
    """A study with a log takes the verdicts logged for the same export and traces (a
    stopped study of hours goes on where it ended) and judges only the rest; a verdict
    logged on other traces is not taken."""
    log = tmp_path / "study.jsonl"
    runs = [RandomRun(1, scans=300)]
    first = Choice(per_block=2, only="_Control")
    judged: list = []
    part = run_study("conveyor_robot", runs, choice=first, log=log, progress=judged.append)
    assert len(part.judged) == len(judged) == 2 and len(log.read_text().splitlines()) == 2
    judged.clear()
    whole = run_study("conveyor_robot", runs, choice=Choice(per_block=2), log=log,
                      progress=judged.append)
    assert {j.mutant.key() for j in judged}.isdisjoint(j.mutant.key() for j in part.judged)
    assert len(whole.judged) == len(judged) + 2
    again = run_study("conveyor_robot", runs, choice=Choice(per_block=2))
    # (the same verdicts; a counterexample z3 gives may be another one)
    assert [(j.mutant.key(), j.outcome) for j in again.judged] == [
        (j.mutant.key(), j.outcome) for j in whole.judged]
    judged.clear()
    other = run_study("conveyor_robot", [RandomRun(2, scans=300)], choice=first, log=log,
                      progress=judged.append)
    assert len(judged) == len(other.judged) == 2


@pytest.mark.parametrize("name", ["palletizer", "sorting"])
def test_the_first_scans_history_is_caught(name):
    """The first cycle's history (the program's `IF NOT Started` block): an order's history
    TRUE at the first scan hides its rise there from a monitor, the block skipped leaves an
    input's history FALSE. The study's runs meet a random first scan in 4 runs only; 40
    short manual runs, random inputs and requests from the first scan, catch each mutant
    the study lists as caught by this test."""
    listed = [key for key, why in CAUGHT_BY_TESTS[name].items() if FIRST_SCAN_TEST in why]
    assert listed
    rec, traces = record(name, [RandomRun(seed, scans=4, manual=True)
                                for seed in range(100, 140)])
    assert replay(rec, traces, rec.text)[0] is None
    by_key = {m.key(): m for m in mutants(rec.text)}
    for key in listed:
        found, _ran = replay(rec, traces, by_key[key].apply(rec.text))
        assert found is not None and ", scan 1 (t = 0 us)" in found, (key, found)


@pytest.mark.parametrize(("name", "fault"), [("cispi_valve", "F2"), ("cispi_subsystem", "F1")])
def test_observe_mode_masks_no_order_on_the_plc(name, fault):
    """In observe mode the diagnosers' flags are set and nothing uses them: the program of a
    cell with diagnosers under a fault of its campaign's observe runs, the filter
    correcting, agrees with the engine scan by scan; with `Ftc` always TRUE (the mutant
    `AND -> OR`, which the study's runs, all in FTC mode, do not tell apart) its filter
    masks the flagged actuator's orders and it does not."""
    run = next(r for r in export_traces(name) if r[4] == "observe"
               and [i.code for i in r[1]] == [fault])  # (the subsystem's: V1's F1)
    _name, injections, until, _policy, diagnosis, control = run
    rec, traces = record(name, [(name, injections, until, "correct", diagnosis, control)])
    assert replay(rec, traces, rec.text)[0] is None
    ftc = "Ftc := (DiagnosisMode <> 1) AND (DiagnosisMode <> 2)"
    assert ftc in rec.text
    found, _ran = replay(rec, traces, rec.text.replace(ftc, ftc.replace("AND", "OR"), 1))
    # (the run that differs is the fault's: "correct/observe/F2..." for the valve,
    # "correct/observe/V1.F1@30s..." for the subsystem)
    assert found is not None and found.startswith("correct/observe/"), found
    assert found.split(",")[0].split("/")[2].split("@")[0].split(".")[-1].startswith(fault)


@pytest.mark.slow
def test_every_mutant_of_the_conveyor_robot_export_is_caught_or_equivalent():
    counts = _checked(run_study("conveyor_robot"))
    assert counts["caught"] > 300 and counts["equivalent"] + counts["refuted"] > 0


# The valve's diagnoser has 2,252 mutants (about 1 s of CPU each when it survives the
# traces, most do: its faulty states' code): the slow test judges a seeded sample of this
# many of them and every other mutant; `python -m tests.mutant_study cispi_valve` judges
# them all (docs/plc-export.md gives both figures).
VALVE_DIAGNOSER_SAMPLE = 200


@pytest.mark.slow
def test_the_valve_mutants_are_caught_or_equivalent():
    study = run_study("cispi_valve", choice=Choice(per_diagnoser=VALVE_DIAGNOSER_SAMPLE))
    counts = _checked(study)
    assert len(study.judged) == VALVE_DIAGNOSER_SAMPLE + sum(
        "_Diag_" not in m.pou for m in mutants(record("cispi_valve", [])[0].text))
    assert counts["caught"] > 0 and counts["equivalent"] + counts["refuted"] > 0


# The other three projects' whole studies take hours of CPU, most of it the filter's proof
# for each survivor of the filter (`python -m tests.mutant_study PROJECT --jobs 2 --log F`
# judges them all and goes on where a stopped run ended; docs/plc-export.md gives the
# figures): the slow test judges a seeded sample of this many mutants of each POU.
PER_BLOCK_SAMPLE = 4


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cispi_subsystem", "palletizer", "sorting"])
def test_a_sample_of_each_blocks_mutants_is_caught_or_equivalent(name):
    study = run_study(name, choice=Choice(per_block=PER_BLOCK_SAMPLE))
    counts = _checked(study)
    pous = Counter(m.pou for m in mutants(record(name, [])[0].text))
    assert len(study.judged) == sum(min(n, PER_BLOCK_SAMPLE) for n in pous.values())
    assert counts["caught"] > 0 and counts["equivalent"] + counts["refuted"] > 0
