"""Every instant, not a grid (hmi/studies/explore.py, Explorer.pieces): the exact sweep splits
the cycle into pieces of instants that share a run; the outcome a piece gives is the outcome
of a run at any instant inside it. Checked against brute force: a run at every millisecond
(and at random microseconds) must give its piece's outcome, class, damage, detection, certain
diagnosis and final decision alike; and the figures of `plchmi diagnose` (isolated at some
instant, whatever the instant, share of instants) computed from the pieces equal those of a
1 ms grid."""

from __future__ import annotations

import itertools
import random

import pytest

from hmi.studies.closed_loop import diagnosability, outcome_of, outcomes, summarise
from hmi.studies.explore import Explorer
from hmi.studies.loop_sweep import DIAG_NO_FILTER, FTC
from tests.examples import example

MS = 1_000
CONFIGS = {"observe": DIAG_NO_FILTER, "ftc": FTC}


def signature(r):
    return (r.outcome, r.damage_us, r.damage_kind, r.detected_us, r.certain_us,
            r.certain_label, r.final, r.final_state)


def piece_of(pieces, at_us):
    (found,) = [p for p in pieces if p.first_us <= at_us <= p.last_us]
    return found


def check_against_runs(ex: Explorer, fault: str, intervals, extra_instants=()):
    """Pieces of `intervals` and runs at every ms of them (and `extra_instants`): the same."""
    before = len(ex.graph.starts)
    for k, lo, hi in intervals:
        ex.pieces(fault, k, lo, hi)
    pieces = outcomes(ex.graph)[before:]
    # the pieces cover each interval exactly, in order, without overlap
    for _, lo, hi in intervals:
        covered = sorted((p.first_us, p.last_us) for p in pieces if lo <= p.first_us <= hi)
        assert covered[0][0] == lo and covered[-1][1] == hi
        assert all(b[0] == a[1] + 1 for a, b in itertools.pairwise(covered))
    starts = [ex.run(fault, k, at, record=False) for k, lo, hi in intervals
              for at in [*range(lo - 1 + MS, hi + 1, MS),
                         *(t for t in extra_instants if lo <= t <= hi)]]
    summaries = summarise(ex.graph)
    for start in starts:
        got = outcome_of(start, summaries[start.node], ex.period)
        assert signature(got) == signature(piece_of(pieces, start.at_us)), (fault, start.at_us)
    return pieces, len(starts)


@pytest.mark.parametrize("fault,config,first", [
    ("F13", "ftc", 300), ("F11", "observe", 580), ("F7", "observe", 480),
    ("F12", "ftc", 0)])
def test_every_instant_of_an_interval_gives_its_piece_outcome(fault, config, first):
    """Twelve scan intervals of the cycle where the fault's outcome changes within an
    interval (a jam as the closing starts, a valve leaving by itself as the program orders
    it), at every millisecond and at 36 random microseconds."""
    ex = Explorer(example("cispi_valve"), CONFIGS[config], "cycles")
    chosen = ex.intervals()[first:first + 12]
    rng = random.Random(f"{fault}{config}")
    extra = [rng.randint(lo, hi) for _, lo, hi in chosen for _ in range(3)]
    pieces, checked = check_against_runs(ex, fault, chosen, extra)
    assert checked == 120 + len(extra)
    assert len(pieces) >= len(chosen)


def test_a_piece_shorter_than_a_scan_is_found_and_right():
    """F13 under FTC: a jam exactly at a scan instant stalls the motor a scan later than one
    a microsecond earlier, which the stall tolerance (more than 1 s) turns into a different
    damage scan: such an instant is a piece of its own, and the runs agree."""
    ex = Explorer(example("cispi_valve"), FTC, "cycles")
    intervals = ex.intervals()
    before = len(ex.graph.starts)
    for k, lo, hi in intervals[300:310]:  # the closing starts (5.96 s)
        ex.pieces("F13", k, lo, hi)
    pieces = outcomes(ex.graph)[before:]
    singles = [p for p in pieces if p.weight == 1]
    assert singles
    for p in singles[:3]:
        start = ex.run("F13", (p.at_us - 1) // ex.period, p.at_us, record=False)
        got = outcome_of(start, summarise(ex.graph)[start.node], ex.period)
        assert signature(got) == signature(p)
        start = ex.run("F13", (p.at_us - 2) // ex.period, p.at_us - 1, record=False)
        other = outcome_of(start, summarise(ex.graph)[start.node], ex.period)
        assert signature(other) != signature(p)


def on_grid(piece, step_us: int = MS) -> bool:
    """Whether a piece holds an instant of the grid."""
    return piece.last_us // step_us * step_us >= piece.first_us


@pytest.mark.slow
@pytest.mark.parametrize("config", ["observe", "ftc"])
def test_the_exact_figures_equal_a_1ms_grid_on_the_valve(config):
    """Every fault over the whole cycle: the pieces, and a run every millisecond (7,840 per
    fault). Every grid run gives its piece's outcome; `diagnose`'s figures are those of the
    grid: the same faults isolated at some instant and whatever the instant (where they
    differ, only because a piece lies between two grid instants, which the exact sweep sees
    and the grid misses), and shares within the pieces shorter than the grid's step."""
    project = example("cispi_valve")
    conf = CONFIGS[config]
    exact = Explorer(project, conf, "cycles")
    faults = [f"F{n}" for n in range(1, 14)]
    exact.explore(faults, None)
    pieces = outcomes(exact.graph)
    grid = Explorer(project, conf, "cycles")
    grid.explore(faults, grid.instants(extras=False, step_us=MS))
    runs = outcomes(grid.graph)
    by_fault = {f: [p for p in pieces if p.fault == f] for f in faults}
    for r in runs:
        assert signature(r) == signature(piece_of(by_fault[r.fault], r.at_us)), (r.fault,
                                                                                   r.at_us)
    ex, gr = diagnosability(conf, pieces, faults), diagnosability(conf, runs, faults)
    for f in faults:
        off = [p for p in by_fault[f] if not on_grid(p)]
        if f in gr.guaranteed and f not in ex.guaranteed:
            assert any(not p.isolated for p in off), f
        if f in ex.isolable and f not in gr.isolable:
            assert any(p.isolated for p in off), f
        short = sum(1 for p in by_fault[f] if p.weight < MS)
        e = next(x for x in ex.faults if x.fault == f)
        g = next(x for x in gr.faults if x.fault == f)
        assert abs(e.share - g.share) <= short * MS / exact.graph.cycle_length / \
            exact.period + 1e-9, f
    assert ex.misdiagnoses == gr.misdiagnoses == 0
