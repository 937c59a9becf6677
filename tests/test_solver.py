"""The two correction strategies against the paper and against brute force."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.engine.solver import exact_solve, is_safe, paper_solve, paper_subsets, tie_key


def bits(ham: list[bool]) -> str:
    return "".join("1" if b else "0" for b in ham)


def test_enumeration_order_is_the_papers():
    # 004 §5.2: "for 3 bits ... 100, 010, 001, 110, 101, 011 and finally 111".
    order = [bits(h) for k in (1, 2, 3) for h in paper_subsets(3, k)]
    assert order == ["100", "010", "001", "110", "101", "011", "111"]


def test_enumeration_is_every_k_subset_once_in_colex_order():
    for n in range(1, 9):
        for k in range(1, n + 1):
            got = [tuple(i for i, b in enumerate(h) if b) for h in paper_subsets(n, k)]
            colex = sorted(itertools.combinations(range(n), k), key=lambda c: c[::-1])
            assert got == colex


def test_paper_returns_the_first_closest_that_solves():
    # CSc: o0.o1 (violated). Flipping o0 or o1 solves; o0 comes first in the paper's order.
    sol = paper_solve(0b011, [(0b011, 0)], unforced=0b111)
    assert sol.how == "closest" and sol.vector == 0b010 and sol.tested == 2


def test_paper_memorises_the_farthest_and_uses_it_when_no_closest_solves():
    # Free outputs o0..o3 all at 1; safe only when at most one is still 1: (a.b) for every
    # pair. Distance 3 is the minimum, beyond Noc/2 = 2: only a farthest can reach it.
    pairs = [((1 << a) | (1 << b), 0) for a, b in itertools.combinations(range(4), 2)]
    sol = paper_solve(0b1111, pairs, unforced=0b1111)
    assert sol.how == "farthest" and sol.distance == 3
    assert is_safe(sol.vector, pairs)
    assert exact_solve(0b1111, pairs, 0b1111).distance == 3


def test_paper_worst_case_complements_every_free_output():
    # Only the all-zero vector of o0..o2 is safe from 111: distance Noc = 3.
    cons = [(1 << a, 0) for a in range(3)]
    sol = paper_solve(0b111, cons, unforced=0b111)
    assert sol.how == "worst case" and sol.vector == 0 and sol.distance == 3


def test_paper_final_fallback_is_fig2s_last_line():
    # o0 must be 0 (its own combined pair with itself is impossible to satisfy): no solution.
    cons = [(0b01, 0), (0, 0b01)]  # o0 and not o0, both active: unsatisfiable
    sol = paper_solve(0b01, cons, unforced=0b11, f0=0b100, f1=0b1000)
    assert sol.vector is None and sol.how == "none"
    assert sol.paper_fallback == ~0b100 & 0b1000
    assert exact_solve(0b01, cons, 0b11).vector is None


def test_papers_literal_gg_misses_a_repair_outside_the_violated_constraints():
    # c1 = o0.o1 is violated. Repairing it by o0 violates c2 = not o0 . o2, by o1 violates
    # c3 = not o1 . o3; the cheapest safe vector flips o0 and o2 (outside the paper's GG).
    cons = [(0b0011, 0), (0b0100, 0b0001), (0b1000, 0b0010)]
    start = 0b1111
    literal = paper_solve(start, cons, unforced=0b1111, rule="violated")
    assert literal.vector is None  # the paper's initCSC would fall back
    widened = paper_solve(start, cons, unforced=0b1111)
    exact = exact_solve(start, cons, unforced=0b1111)
    assert widened.distance == exact.distance == 2
    assert is_safe(widened.vector, cons) and is_safe(exact.vector, cons)


def test_exact_tie_break_prefers_switching_off_then_sparing_the_first_outputs():
    # c1 = o0.o1 (both on): flip o0 or o1, both switch an order off: spare o0, flip o1.
    assert exact_solve(0b11, [(0b11, 0)], 0b11).vector == 0b01
    # c = o0 . not o1: flip o0 (off) or o1 (on): switching off wins even though o0 is first.
    assert exact_solve(0b01, [(0b01, 0b10)], 0b11).vector == 0b00


def test_exact_tests_far_fewer_vectors_than_paper_on_a_wide_problem():
    # 24 free outputs, 4 independent violated pairs: minimum distance 4.
    cons = [((1 << 2 * i) | (1 << 2 * i + 1), 0) for i in range(4)]
    start = 0xFF
    free = (1 << 24) - 1
    # Widen the free set with inactive-but-active constraints over the other outputs.
    cons += [((1 << k), (1 << (k + 1))) for k in range(8, 23, 2)]
    paper = paper_solve(start, cons, free)
    exact = exact_solve(start, cons, free)
    assert paper.distance == exact.distance == 4
    # Counts are deterministic: 2375 vectors for the paper's enumeration, 53 for exact.
    assert exact.tested * 20 <= paper.tested


def brute_min(start: int, cons, unforced: int, n: int) -> int | None:
    best = None
    forced_part = start & ~unforced
    for v in range(1 << n):
        if v & ~unforced != forced_part:
            continue
        if is_safe(v, cons):
            d = (v ^ start).bit_count()
            best = d if best is None else min(best, d)
    return best


@st.composite
def problems(draw):
    n = draw(st.integers(1, 12))
    m = draw(st.integers(0, 2 * n))
    cons = []
    for _ in range(m):
        size = draw(st.integers(1, min(4, n)))
        outs = draw(st.lists(st.integers(0, n - 1), min_size=size, max_size=size, unique=True))
        pos = neg = 0
        for o in outs:
            if draw(st.booleans()):
                pos |= 1 << o
            else:
                neg |= 1 << o
        cons.append((pos, neg))
    start = draw(st.integers(0, (1 << n) - 1))
    unforced = draw(st.integers(0, (1 << n) - 1))
    return n, cons, start, unforced


def brute_best(start: int, cons, unforced: int, n: int) -> int | None:
    """The safe vector the exact strategy's documented rule picks, by enumeration."""
    best = None
    for v in range(1 << n):
        if v & ~unforced != start & ~unforced or not is_safe(v, cons):
            continue
        flipped = v ^ start
        key = (flipped.bit_count(), tie_key(flipped, start))
        if best is None or key < best[0]:
            best = (key, v)
    return None if best is None else best[1]


@settings(max_examples=300, deadline=None)
@given(problems())
def test_exact_picks_the_brute_force_vector_including_the_tie_break(problem):
    n, cons, start, unforced = problem
    expected = brute_best(start, cons, unforced, n)
    sol = exact_solve(start, cons, unforced)
    assert sol.vector == expected
    assert sol.how == ("none" if expected is None else
                       "unchanged" if expected == start else "minimal")


@settings(max_examples=400, deadline=None)
@given(problems())
def test_both_strategies_find_the_brute_force_minimum(problem):
    n, cons, start, unforced = problem
    expected = brute_min(start, cons, unforced, n)
    for sol in (paper_solve(start, cons, unforced), exact_solve(start, cons, unforced)):
        if expected is None:
            assert sol.vector is None
        else:
            assert sol.vector is not None and is_safe(sol.vector, cons)
            assert sol.distance == expected
            assert sol.vector & ~unforced == start & ~unforced  # forced outputs untouched
