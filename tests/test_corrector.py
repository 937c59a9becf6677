"""The bounded corrector.

The exact search against an independent MaxSAT solver (RC2 of python-sat, given the
tie-break as weights; brute force is in test_solver.py); infeasibility proved without
enumerating; the step budget (deterministic, per scan, the safe state written and said so);
the live wall-clock net; and each strategy's note stating its own rule.
"""

from __future__ import annotations

import itertools
import random

import pytest
from pysat.examples.rc2 import RC2
from pysat.formula import WCNF

from hmi.bench.corrector import dense_row, infeasible, planted
from hmi.cli import main
from hmi.engine.commands import ManualOutput, SetMode
from hmi.engine.sat import solve_sat
from hmi.engine.scan import Engine
from hmi.engine.solver import Problem, exact_solve, is_safe, paper_solve
from hmi.errors import ProjectError
from hmi.explain.journal import read
from hmi.plant.sim.plant import SimPlant
from hmi.project.loader import load_project
from hmi.session.live import arm_search_deadline
from hmi.session.session import Session
from tests.conftest import PROJECTS, write_project

S = 1_000_000


# -- minimality ------------------------------------------------------------------------------

def rc2_best(start: int, cons, unforced: int, n: int) -> int | None:
    """The same choice by RC2 (weighted partial MaxSAT): hard clauses are the constraints and
    the forced outputs; keeping output k as it is weighs D + (O if switching it on) +
    2^(n-1-k), the documented order (distance, then orders switched on, then priority)."""
    wcnf = WCNF()
    for pos, neg in cons:
        wcnf.append([-(k + 1) for k in range(n) if pos >> k & 1]
                    + [k + 1 for k in range(n) if neg >> k & 1])
    for k in range(n):
        keep = k + 1 if start >> k & 1 else -(k + 1)
        if not unforced >> k & 1:
            wcnf.append([keep])
        else:
            wcnf.append([keep], weight=(1 << (n + 8)) + (0 if start >> k & 1 else 1 << n)
                        + (1 << (n - 1 - k)))
    with RC2(wcnf) as rc2:
        model = rc2.compute()
    if model is None:
        return None
    return sum(1 << (lit - 1) for lit in model if 0 < lit <= n)


def random_instances(seed: int):
    """64 outputs: planted dense ones (200 constraints) at every distance up to 12, and
    unplanted sparser ones with forced outputs (some of them infeasible)."""
    rng = random.Random(seed)
    for d in (1, 2, 3, 4, 6, 8, 10, 12):
        inst = planted(rng, 64, 200, d)
        yield inst.start, inst.combined, inst.unforced
    for _ in range(16):
        cons = []
        for _ in range(rng.randint(40, 140)):
            pos = neg = 0
            for k in rng.sample(range(64), rng.choice((2, 2, 3, 4))):
                if rng.random() < 0.6:
                    pos |= 1 << k
                else:
                    neg |= 1 << k
            cons.append((pos, neg))
        unforced = (1 << 64) - 1
        for k in rng.sample(range(64), rng.randint(0, 12)):
            unforced &= ~(1 << k)
        yield rng.getrandbits(64), cons, unforced


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_exact_agrees_with_an_independent_maxsat_solver_at_64_outputs(seed):
    outcomes = set()
    for start, cons, unforced in random_instances(seed):
        expected = rc2_best(start, cons, unforced, 64)
        sol = exact_solve(start, cons, unforced)
        assert sol.vector == expected, (seed, start, cons, unforced)
        outcomes.add(sol.how)
    assert "minimal" in outcomes  # the instances are not all trivial


def test_paper_reaches_the_same_distance_on_dense_instances_it_can_enumerate():
    for d in (1, 2):
        for inst in dense_row(d, 3, seed=4):
            paper = paper_solve(inst.start, inst.combined, inst.unforced)
            assert paper.distance == d and is_safe(paper.vector, inst.combined)


def test_a_prepared_problem_answers_like_a_fresh_one_for_any_start():
    rng = random.Random(9)
    inst = planted(rng, 64, 200, 6)
    problem = Problem(inst.combined, inst.unforced)
    for _ in range(20):
        start = inst.start ^ rng.getrandbits(64) & rng.getrandbits(64) & rng.getrandbits(64)
        again = problem.solve(start)
        fresh = exact_solve(start, inst.combined, inst.unforced)
        assert (again.vector, again.how) == (fresh.vector, fresh.how)


# -- infeasibility ---------------------------------------------------------------------------

@pytest.mark.parametrize("pairs,linked", [(11, False), (11, True), (31, False), (31, True)])
def test_infeasibility_is_proved_in_a_bounded_number_of_steps(pairs, linked):
    # The reported family (22 outputs in violated pairs, two in all four sign patterns) took
    # seconds per scan by enumeration; each extra output doubled it. Steps are deterministic.
    inst = infeasible(pairs, linked)
    sol = exact_solve(inst.start, inst.combined, inst.unforced)
    assert sol.vector is None and sol.how == "none"
    assert sol.steps < 1_000
    core = set(range(pairs, pairs + 4))  # x.y, x.!y, !x.y, !x.!y
    assert core <= set(sol.involved)
    if not linked:
        assert set(sol.involved) == core  # the pairs can be repaired: not part of the cause


def test_the_paper_strategy_enumerates_until_its_budget():
    inst = infeasible(11)
    sol = paper_solve(inst.start, inst.combined, inst.unforced, budget=20_000)
    assert sol.how == "budget" and sol.vector is None
    assert 20_000 < sol.steps <= 20_000 + len(inst.combined)


def test_the_sat_check_finds_models_and_refutations():
    rng = random.Random(3)
    for _ in range(300):
        n = rng.randint(1, 8)
        clauses = [[2 * k + rng.randint(0, 1) for k in rng.sample(range(n), rng.randint(1, 3)
                                                                   if n >= 3 else 1)]
                   for _ in range(rng.randint(0, 30))]
        result = solve_sat(range(n), clauses, phase=rng.getrandbits(n))
        models = [m for m in range(1 << n)
                  if all(any((m >> (lit >> 1) & 1) == lit & 1 for lit in c) for c in clauses)]
        assert (result.status == "sat") == bool(models)
        if models:
            assert result.model in models


# -- the budget ------------------------------------------------------------------------------

def test_the_step_budget_stops_the_search_deterministically():
    instances = dense_row(12, 3, seed=2)
    for inst in instances:
        free = exact_solve(inst.start, inst.combined, inst.unforced)
        assert free.how == "minimal" and free.steps > 300
        first = exact_solve(inst.start, inst.combined, inst.unforced, budget=300)
        second = exact_solve(inst.start, inst.combined, inst.unforced, budget=300)
        assert first.how == "budget" and first.vector is None
        assert first == second
        assert 300 < first.steps < 300 + 2 * len(inst.combined)
        enough = exact_solve(inst.start, inst.combined, inst.unforced, budget=free.steps)
        assert enough.vector == free.vector


def test_a_deadline_in_the_past_stops_both_strategies():
    inst = dense_row(12, 1, seed=2)[0]
    problem = Problem(inst.combined, inst.unforced)
    assert problem.solve(inst.start, deadline=0.0).how == "deadline"
    wide = infeasible(11)
    assert paper_solve(wide.start, wide.combined, wide.unforced, deadline=0.0).how == \
        "deadline"


PAIRS = """\
name: pairs
scan_period: 10ms
inputs: {i0: switch}
outputs: {PAIRS_OUTPUTS}
control:
  equations: {PAIRS_EQUATIONS}
constraints:
PAIRS_CONSTRAINTS
plant: {kind: sim, model: valve, ports: {fsc: i0}}
"""


def pairs_project(tmp_path, extra: str = "", n: int = 12):
    """n outputs all asked on; every pair of them forbidden while i0: keep one only."""
    outs = [f"o{k}" for k in range(n)]
    text = (PAIRS.replace("PAIRS_OUTPUTS", ", ".join(f"{o}: output {o}" for o in outs))
            .replace("PAIRS_EQUATIONS", ", ".join(f"{o}: i0" for o in outs))
            .replace("PAIRS_CONSTRAINTS\n", "".join(
                f"  K{a}_{b}: o{a} and o{b} and i0\n"
                for a, b in itertools.combinations(range(n), 2))))
    return write_project(tmp_path / "pairs", {"project.yaml": text + extra})


def engine_for(folder, **kwargs) -> Engine:
    project = load_project(folder)
    plant = SimPlant(project)
    plant.free_inputs["i0"] = True
    return Engine(project, plant, **kwargs)


def test_past_its_budget_the_filter_writes_the_safe_state_and_says_so(tmp_path):
    folder = pairs_project(tmp_path, "solver_budget: 300\n")
    engine = engine_for(folder)
    assert engine.safety_filter.budget == 300
    cell = Session(engine).scan_once()  # the session explains the scan
    report = cell.snapshot.filter_report
    assert cell.snapshot.outputs == (False,) * 12
    assert report.safe_state and not report.unsafe_written
    assert report.stopped == "budget" and report.steps > 300 and report.budget == 300
    assert "used its budget" in report.fallback and "of 300 steps" in report.fallback
    explanation = next(e for e in cell.explanations if e.key == "search_budget")
    assert explanation.alarm and explanation.severity == "high"
    assert "safe state written" in explanation.what
    assert {p.id for p in explanation.policies} >= {"manual", "budget"}
    assert any(a.key == "search_budget" for a in cell.alarms)
    # With the budget it needs, the same situation is corrected: one output kept, o0 (the
    # first listed) spared.
    roomy = engine_for(folder, solver_budget=5_000).step(0)
    assert roomy.outputs == (True,) + (False,) * 11 and not roomy.filter_report.stopped


def test_a_budget_stop_is_counted_journalled_and_repeatable(tmp_path, capsys):
    folder = pairs_project(tmp_path, "solver_budget: 300\n")
    traces = []
    for k in range(2):
        journal = tmp_path / f"j{k}.jsonl"
        trace = tmp_path / f"t{k}.csv"
        assert main(["run", str(folder), "--for", "0.5s", "--journal", str(journal),
                     "--trace", str(trace)]) == 0
        out = capsys.readouterr().out
        assert "(of which fallbacks 51, 51 at the search budget)" in out
        alarms = [e for e in read(journal).entries if e["type"] == "alarm"]
        assert any(e["key"] == "search_budget" and e["event"] == "raised" for e in alarms)
        traces.append(trace.read_bytes())
    assert traces[0] == traces[1]
    assert main(["run", str(folder), "--for", "0.5s", "--solver-budget", "5000",
                 "--journal", str(tmp_path / "j.jsonl")]) == 0
    assert "fallbacks 0" in capsys.readouterr().out


def test_the_budget_is_checked_where_it_is_given(tmp_path, capsys):
    folder = pairs_project(tmp_path, "solver_budget: 50\n", n=3)
    with pytest.raises(ProjectError) as err:
        load_project(folder)
    text = str(err.value)
    assert "project.yaml:" in text and "solver_budget" in text and "100" in text
    good = pairs_project(tmp_path, "", n=3)
    for value, said in (("ten", "not a whole number of steps"), ("99", "out of range")):
        with pytest.raises(SystemExit) as exited:
            main(["run", str(good), "--for", "1s", "--solver-budget", value])
        assert exited.value.code == 2 and said in capsys.readouterr().err
    assert load_project(good).solver_budget is None
    assert engine_for(good).safety_filter.budget == 5_000  # half of the 10 ms period, in steps


def test_only_a_live_runner_arms_the_wall_clock_net(tmp_path):
    engine = engine_for(pairs_project(tmp_path))
    session = Session(engine)
    assert engine.safety_filter.wall_limit_us is None  # headless: traces depend on steps only
    arm_search_deadline(session)
    assert engine.safety_filter.wall_limit_us == 5_000  # half the 10 ms period
    engine.safety_filter.wall_limit_us = 1e-6  # a machine far too slow: the net stops the search
    snap = engine.step(0)
    assert snap.filter_report.stopped == "deadline" and snap.outputs == (False,) * 12
    assert "wall-clock limit" in snap.filter_report.fallback


# -- each strategy's note states its own rule ------------------------------------------------

AB = """
    name: ab
    scan_period: 10ms
    inputs: {i0: switch}
    outputs: {A: order A, B: order B}
    control:
      equations: {A: i0, B: i0}
    constraints:
      K: A and B
    plant: {kind: sim, model: valve, ports: {fsc: i0}}
"""


def ab_report(tmp_path, solver: str):
    folder = write_project(tmp_path / f"ab_{solver}", {"project.yaml": AB})
    engine = engine_for(folder, solver=solver)
    snap = engine.step(0)
    return snap.outputs, snap.filter_report


def test_the_exact_note_states_the_exact_tie_break(tmp_path):
    outputs, report = ab_report(tmp_path, "exact")
    assert outputs == (True, False)  # B changed: A, listed first, is spared
    assert report.note.startswith("exact search: 1 output changed for K")
    assert "ties go to switching orders off, then to sparing the outputs listed first" in \
        report.note


def test_the_paper_note_states_the_papers_order_not_the_exact_tie_break(tmp_path):
    outputs, report = ab_report(tmp_path, "paper")
    assert outputs == (False, True)  # the paper's first 1-subset changes A
    assert report.note.startswith("paper search (Algorithm 1 of 004): 1 output changed for K")
    assert "the first safe vector in the paper's enumeration order" in report.note
    assert "no tie-break" in report.note and "free outputs in order: A, B" in report.note
    assert "sparing the outputs listed first" not in report.note


def test_the_paper_note_names_a_farthest_repair(tmp_path):
    # Four outputs asked on, every pair forbidden: distance 3 is beyond Noc/2 = 2, so only a
    # farthest vector of Algorithm 1 reaches it.
    folder = pairs_project(tmp_path, "", n=4)
    snap = engine_for(folder, solver="paper").step(0)
    assert snap.filter_report.distance == 3
    assert "the memorised farthest vector" in snap.filter_report.note


def test_the_paper_strategy_stops_the_pump_where_the_project_keeps_it_running():
    # cispi_subsystem declares P first so that, when running the pump and closing V2 conflict
    # (CSc2 at 4 s with the faulty program), the valve waits. The exact strategy does; the
    # paper's order changes the first free output first, and stops the pump.
    project = load_project(PROJECTS / "cispi_subsystem")
    written = {}
    for solver in ("exact", "paper"):
        session = Session(Engine(project, SimPlant(project), control="faulty",
                                       solver=solver))
        cells = []
        session.run_for(4 * S + 1, cells.append)
        snap = next(c.snapshot for c in cells if "CSc2" in c.snapshot.filter_report.violated_names)
        assert snap.time_us == 4 * S
        written[solver] = dict(zip(snap.layout.outputs, snap.outputs, strict=True))
        note = snap.filter_report.note
        assert ("ties go to switching orders off" in note) == (solver == "exact")
    assert written["exact"]["P"] and not written["exact"]["C2"]
    assert not written["paper"]["P"] and written["paper"]["C2"]


def test_manual_requests_meet_the_same_bounded_corrector(tmp_path):
    folder = pairs_project(tmp_path, "solver_budget: 300\n", n=12)
    engine = engine_for(folder)
    session = Session(engine)
    session.command(SetMode(True))
    for k in range(12):
        session.command(ManualOutput(f"o{k}", True))
    snap = session.scan_once()
    assert snap.snapshot.filter_report.stopped == "budget"
    assert snap.snapshot.outputs == (False,) * 12
