"""A small CDCL SAT solver: the corrector's proof that no safe vector exists.

Why a SAT solver at all: the closest-vector search (hmi.engine.solver) can only say "none"
after ruling out every distance, which costs exponential time when the situation is
infeasible (two outputs in all four sign patterns next to a dozen violated pairs took seconds
per scan). Conflict-driven clause learning proves such a situation infeasible in a handful of
conflicts: a conflict between two outputs is learned once, as a clause, instead of being
rediscovered under every assignment of the unrelated outputs.

Variables are output indices k; literal 2k + b means "output k is b". A clause is satisfied
when one of its literals holds. The solver is the textbook one (two watched literals, first-UIP
learning, non-chronological backjumping, activity-ordered decisions with a fixed phase) and
counts its work in *steps* (a clause visited, a decision): the caller's budget is a number of
steps, so the outcome never depends on the machine's speed.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from typing import NamedTuple


class SatResult(NamedTuple):
    status: str  # "sat", "unsat", "budget" (the budget ran out first) or "deadline"
    model: int  # with "sat": bit k set when output k is 1 (variables not asked about: 0)
    steps: int  # clause visits and decisions


def solve_sat(variables: Sequence[int], clauses: Iterable[Sequence[int]], phase: int = 0,
              budget: int | None = None, deadline: float | None = None,
              clean: bool = False) -> SatResult:
    """Satisfy `clauses` over `variables` (output indices); decisions take the value the
    output has in `phase` (the corrector passes the vector it starts from), so a model found
    without conflicts is the phase itself. `clean`: every clause already names each variable
    once and every variable is in `variables` (the corrector's are), so they are taken as
    they are."""
    size = max(variables, default=-1) + 1
    if not clean:
        for clause in clauses:
            for lit in clause:
                size = max(size, (lit >> 1) + 1)
    val = [-1] * size
    level = [0] * size
    reason = [-1] * size
    activity = [0.0] * size
    watches: list[list[int]] = [[] for _ in range(2 * size)]
    stored: list[list[int]] = []
    trail: list[int] = []
    limits: list[int] = []  # trail length when each decision level began
    units: list[int] = []
    for clause in clauses:
        if clean:
            lits = list(clause)
        else:
            lits = sorted(set(clause))
            if any(lit ^ 1 in lits for lit in lits):
                continue  # a tautology holds whatever the values
        if not lits:
            return SatResult("unsat", 0, 0)
        if len(lits) == 1:
            units.append(lits[0])
            continue
        watches[lits[0]].append(len(stored))
        watches[lits[1]].append(len(stored))
        stored.append(lits)
    steps = 0
    qhead = 0
    bump = 1.0

    def enqueue(lit: int, why: int) -> None:
        k = lit >> 1
        val[k] = lit & 1
        level[k] = len(limits)
        reason[k] = why
        trail.append(lit)

    def propagate() -> int:
        """Unit propagation from qhead; returns a conflicting clause's index, or -1."""
        nonlocal qhead, steps
        while qhead < len(trail):
            false_lit = trail[qhead] ^ 1
            qhead += 1
            watching = watches[false_lit]
            kept: list[int] = []
            i = 0
            count = len(watching)
            while i < count:
                ci = watching[i]
                i += 1
                steps += 1
                c = stored[ci]
                if c[0] == false_lit:
                    c[0], c[1] = c[1], false_lit
                first = c[0]
                first_val = val[first >> 1]
                if first_val == first & 1:
                    kept.append(ci)  # satisfied by the other watch
                    continue
                for t in range(2, len(c)):
                    lit = c[t]
                    v = val[lit >> 1]
                    if v < 0 or v == lit & 1:
                        c[1] = lit
                        c[t] = false_lit
                        watches[lit].append(ci)
                        break
                else:
                    kept.append(ci)
                    if first_val >= 0:  # every literal false
                        kept.extend(watching[i:])
                        watches[false_lit] = kept
                        return ci
                    enqueue(first, ci)
            watches[false_lit] = kept
        return -1

    def backtrack(to_level: int) -> None:
        nonlocal qhead
        if len(limits) <= to_level:
            return
        start = limits[to_level]
        for lit in trail[start:]:
            k = lit >> 1
            val[k] = -1
            reason[k] = -1
        del trail[start:]
        del limits[to_level:]
        qhead = len(trail)

    def analyse(conflict: int) -> tuple[list[int], int]:
        """First-UIP learning: the learnt clause and the level to jump back to."""
        nonlocal bump
        seen = [False] * size
        learnt = [0]
        pending = 0
        current = len(limits)
        clause = stored[conflict]
        skip_first = False
        index = len(trail) - 1
        while True:
            for lit in clause[1:] if skip_first else clause:
                k = lit >> 1
                if not seen[k] and level[k] > 0:
                    seen[k] = True
                    activity[k] += bump
                    if level[k] == current:
                        pending += 1
                    else:
                        learnt.append(lit)
            while not seen[trail[index] >> 1]:
                index -= 1
            p = trail[index]
            index -= 1
            seen[p >> 1] = False
            pending -= 1
            if pending == 0:
                break
            clause = stored[reason[p >> 1]]
            skip_first = True  # a reason clause holds its implied literal first
        learnt[0] = p ^ 1
        bump *= 1.05
        if bump > 1e100:
            for k in range(size):
                activity[k] *= 1e-100
            bump *= 1e-100
        if len(learnt) == 1:
            return learnt, 0
        best = max(range(1, len(learnt)), key=lambda j: level[learnt[j] >> 1])
        learnt[1], learnt[best] = learnt[best], learnt[1]
        return learnt, level[learnt[1] >> 1]

    for lit in units:
        v = val[lit >> 1]
        if v < 0:
            enqueue(lit, -1)
        elif v != lit & 1:
            return SatResult("unsat", 0, steps)
    order = sorted(set(variables))
    cursor = 0
    while True:
        conflict = propagate()
        if budget is not None and steps > budget:
            return SatResult("budget", 0, steps)
        if deadline is not None and time.perf_counter() > deadline:
            return SatResult("deadline", 0, steps)
        if conflict >= 0:
            if not limits:
                return SatResult("unsat", 0, steps)
            learnt, back = analyse(conflict)
            backtrack(back)
            if len(learnt) == 1:
                enqueue(learnt[0], -1)
            else:
                watches[learnt[0]].append(len(stored))
                watches[learnt[1]].append(len(stored))
                stored.append(learnt)
                enqueue(learnt[0], len(stored) - 1)
            continue
        chosen = -1
        if bump == 1.0:
            # No conflict yet: every activity is 0, so the choice is the next unassigned
            # variable in order (nothing has been unassigned since the last decision).
            while cursor < len(order):
                if val[order[cursor]] < 0:
                    chosen = order[cursor]
                    break
                cursor += 1
        else:
            steps += len(order)  # the activity scan reads every variable
            best_activity = -1.0
            for k in order:
                if val[k] < 0 and activity[k] > best_activity:
                    chosen, best_activity = k, activity[k]
        if chosen < 0:
            model = 0
            for k in order:
                if val[k] == 1:
                    model |= 1 << k
            return SatResult("sat", model, steps)
        steps += 1
        limits.append(len(trail))
        enqueue(2 * chosen + (phase >> chosen & 1), -1)
