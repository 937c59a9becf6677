"""Finding the safe output vector closest (in Hamming distance) to what the program asked for.

Vectors are ints: bit k is output k in the project's declaration order. A combined
constraint, once its context (the literals over uncontrollable variables Y) holds, is a pair
of masks over the outputs: it is violated by v when every output it needs at 1 is 1
(`v & pos == pos`) and every output it needs at 0 is 0 (`v & neg == 0`).

Two strategies give the same minimal distance (when they finish within their budget):

* :func:`paper_solve` — Algorithm 1 / Fig. 2 of Pichard, Philippot & Riera (ICINCO 2018):
  k-subsets of the free outputs in increasing k, in the paper's order (a colex successor, ST
  code of Fig. 2), each "closest" k-subset tested together with its complement, the
  "farthest"; the farthest that solves is memorised; if no closest solves, the memorised
  farthest is used, else the worst case (every free output complemented), else Fig. 2's final
  fallback. One deliberate difference, documented in docs/filter.md: the free outputs (the
  paper's GG from initCSC) are the unforced outputs of every *active* combined constraint,
  not only of the violated ones — with the paper's GG a repair that must touch an output of a
  not-yet-violated constraint is missed (tests/test_solver.py shows such a case), and the two
  strategies could not promise the same answer.
* :func:`exact_solve` / :class:`Problem` — branch and bound over the free outputs with unit
  propagation and a bound from violated constraints on disjoint outputs; a small CDCL SAT
  solver (:mod:`hmi.engine.sat`) proves a situation infeasible without enumerating. The
  cost of a set of changes is one integer that orders like (distance, tie-break), so the
  first optimum is the documented choice. Details in :func:`_solve_group`.

Tie-break (exact): fewest outputs switched on (0 -> 1) — removing an order is safer than
adding one; then, outputs being listed in priority order in the project (first = most
important to keep as asked), the set of changed outputs whose most important member is the
least important (compare the sorted index tuples, larger wins). The paper strategy has no
tie-break: the first safe vector in its enumeration order wins.

Budget: both strategies count their work in *steps* — one constraint read against a vector
(propagation, the bound, a paper vector test) or one clause visit / decision of the SAT
solver — and stop past `budget` steps with how "budget" and no vector (the caller writes the
safe state). Counting, not timing, keeps a headless run's trace the same on any machine. A
live run may also pass a wall-clock `deadline` (how "deadline"), a safety net only.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

from hmi.engine.sat import solve_sat

Masks = Sequence[tuple[int, int]]  # (pos, neg) per active combined constraint


def violates(v: int, pos: int, neg: int) -> bool:
    return v & pos == pos and not v & neg


def first_violated(v: int, constraints: Masks) -> int:
    for index, (pos, neg) in enumerate(constraints):
        if v & pos == pos and not v & neg:
            return index
    return -1


def is_safe(v: int, constraints: Masks) -> bool:
    for pos, neg in constraints:
        if v & pos == pos and not v & neg:
            return False
    return True


@dataclass(frozen=True)
class Solution:
    vector: int | None  # None: no safe vector exists over the free outputs
    flipped: int  # bits changed from the start vector
    tested: int  # vectors evaluated against the constraints
    how: str  # "unchanged", "closest", "farthest", "worst case", "minimal", "none", "budget"
    paper_fallback: int | None = None  # Fig. 2's last-resort vector, when it is reached
    steps: int = 0  # work done, in the budget's unit (see the module's docstring)
    budget: int | None = None  # the budget it ran under (None: unbounded)
    involved: tuple[int, ...] = ()  # "none" from exact: the constraints that cannot all hold

    @property
    def distance(self) -> int:
        return self.flipped.bit_count()


# --------------------------------------------------------------------------------------------
# Algorithm 1 (paper)
# --------------------------------------------------------------------------------------------


def paper_subsets(n: int, k: int) -> Iterator[list[bool]]:
    """The k-subsets of n bits in the paper's order (HamMot arrays of Fig. 2).

    First subset: the first k bits set. Next: find the first i with HamMot[i] and not
    HamMot[i+1] (counting the set bits up to i in cpt), move that bit to i+1, clear the bits
    before i and set the first cpt-1 bits. For n = 3: 100 010 001, 110 101 011, 111.
    """
    if not 0 < k <= n:
        return
    ham = [i < k for i in range(n)]
    while True:
        yield list(ham)
        cpt = 0
        i = 0
        found = False
        while i <= n - 2:
            if ham[i]:
                cpt += 1
                if not ham[i + 1]:
                    found = True
                    break
            i += 1
        if not found:
            return
        ham[i] = False
        ham[i + 1] = True
        for j in range(i):
            ham[j] = False
        while cpt > 1:
            ham[cpt - 2] = True
            cpt -= 1


def free_indices(start: int, combined: Masks, unforced: int, rule: str = "active") -> list[int]:
    """The outputs the search may change (the paper's tabMot2), in index order."""
    mask = 0
    for pos, neg in combined:
        if rule == "active" or violates(start, pos, neg):
            mask |= pos | neg
    mask &= unforced
    return [k for k in range(mask.bit_length()) if mask >> k & 1]


def paper_solve(start: int, combined: Masks, unforced: int, f0: int = 0, f1: int = 0,
                rule: str = "active", budget: int | None = None,
                deadline: float | None = None) -> Solution:
    """Algorithm 1 with the enumeration and memorisation of Fig. 2.

    Each vector test costs the constraints it evaluates (up to the first violated one) in
    steps; past `budget` steps the search stops with how "budget" and no vector; past
    `deadline` (a time.perf_counter() value, live runs only) with how "deadline"."""
    m = len(combined)
    steps = 0

    def safe(v: int) -> bool:
        nonlocal steps
        index = first_violated(v, combined)
        steps += m if index < 0 else index + 1
        return index < 0

    tested = 1
    if safe(start):
        return Solution(start, 0, tested, "unchanged", steps=steps)
    index = free_indices(start, combined, unforced, rule)
    noc = len(index)
    bits = [1 << i for i in index]
    all_free = sum(bits)
    max_ham = noc
    farthest_solution: int | None = None
    rounds = 0
    for k in range(1, noc // 2 + 1):
        for ham in paper_subsets(noc, k):
            if budget is not None and steps > budget:
                return Solution(None, 0, tested, "budget", steps=steps, budget=budget)
            rounds += 1
            if deadline is not None and not rounds & 63 and time.perf_counter() > deadline:
                return Solution(None, 0, tested, "deadline", steps=steps, budget=budget)
            flip = 0
            for b, on in zip(bits, ham, strict=True):
                if on:
                    flip |= b
            closest = start ^ flip
            tested += 1
            if safe(closest):
                return Solution(closest, flip, tested, "closest", steps=steps, budget=budget)
            if max_ham > noc - k:
                farthest = start ^ (all_free ^ flip)
                tested += 1
                if safe(farthest):
                    farthest_solution = farthest
                    max_ham = noc - k
    if farthest_solution is not None:
        return Solution(farthest_solution, farthest_solution ^ start, tested, "farthest",
                        steps=steps, budget=budget)
    worst = start ^ all_free
    tested += 1
    if noc and safe(worst):
        return Solution(worst, all_free, tested, "worst case", steps=steps, budget=budget)
    fallback = ~f0 & f1  # Fig. 2: mem[i] := NOT F0s[i] AND F1s[i]
    return Solution(None, 0, tested, "none", paper_fallback=fallback, steps=steps,
                    budget=budget)


# --------------------------------------------------------------------------------------------
# Exact branch and bound
# --------------------------------------------------------------------------------------------


class _OutOfBudget(Exception):
    """The step budget ran out in the middle of a search."""


class _OutOfTime(Exception):
    """A live run's wall-clock deadline passed in the middle of a search."""


class _NeedIncumbent(Exception):
    """The search has looked long without finding any safe vector: ask the SAT solver."""


# Steps the branch and bound may spend before it has found any safe vector; past them the
# SAT solver decides whether one exists (and gives the search its first upper bound).
DIVE_STEPS = 500


def tie_key(flipped: int, start: int) -> tuple[int, tuple[int, ...]]:
    """Smaller is preferred: fewer outputs switched on, then spare the high-priority ones."""
    switched_on = (flipped & ~start).bit_count()
    indices = tuple(k for k in range(flipped.bit_length()) if flipped >> k & 1)
    return (switched_on, tuple(-i for i in indices))


def _bits(mask: int) -> list[int]:
    out = []
    while mask:
        low = mask & -mask
        out.append(low.bit_length() - 1)
        mask ^= low
    return out


class Problem:
    """One set of active combined constraints, prepared for the exact search.

    What depends only on the constraints, the free outputs and the forced outputs' values is
    computed here once: the filter keeps one Problem per set of active constraints (a cell
    meets the same few sets again and again), so a violation scan pays only the search. The
    preparation is linear in the constraints' size and is not counted in the search's steps:
    a step budget means the same whether the Problem was new or reused.

    Reduction: a constraint with a literal on a forced output either cannot be violated (the
    literal is false: dropped) or loses that literal (true, and stays so); one that the forced
    outputs alone violate makes the problem infeasible (`impossible`).
    """

    __slots__ = ("LM", "N", "P", "_clauses", "_components", "forced_values", "impossible", "nb",
                 "occ_items", "origin", "size", "true_items", "unforced")

    def __init__(self, combined: Masks, unforced: int, forced_values: int = 0):
        self.unforced = unforced
        self.forced_values = forced_values & ~unforced
        self.size = len(combined)
        touched = 0
        for pos, neg in combined:
            touched |= pos | neg
        self.nb = nb = max(unforced.bit_length(), touched.bit_length(), 1)
        self.impossible = -1
        if not touched & ~unforced:
            P = [c[0] for c in combined]
            N = [c[1] for c in combined]
            origin = None
        else:
            P, N, origin = [], [], []
            forced = ~unforced
            values = self.forced_values
            for i, (pos, neg) in enumerate(combined):
                fixed_pos = pos & forced
                if values & fixed_pos != fixed_pos or values & neg & forced:
                    continue
                p = pos & unforced
                q = neg & unforced
                if not p | q:
                    self.impossible = i
                    break
                P.append(p)
                N.append(q)
                origin.append(i)
        self.P, self.N, self.origin = P, N, origin
        self.LM = LM = [p | q for p, q in zip(P, N, strict=True)]
        # What propagation reads, per output k: (bit of the constraint, pos, neg, outputs) for
        # each constraint on k; split by the value k must have for its literal to be true.
        pos_items: list[list[tuple[int, int, int, int]]] = [[] for _ in range(nb)]
        neg_items: list[list[tuple[int, int, int, int]]] = [[] for _ in range(nb)]
        for j, (p, q, m) in enumerate(zip(P, N, LM, strict=True)):
            item = (1 << j, p, q, m)
            while p:
                low = p & -p
                pos_items[low.bit_length() - 1].append(item)
                p ^= low
            while q:
                low = q & -q
                neg_items[low.bit_length() - 1].append(item)
                q ^= low
        self.occ_items = [a + b for a, b in zip(pos_items, neg_items, strict=True)]
        self.true_items = (neg_items, pos_items)  # [value of k][k]
        self._components: list[int] | None = None
        self._clauses: dict[int, tuple[int, list[list[int]]]] = {}

    @property
    def components(self) -> list[int]:
        """The constraints (as bit masks) of each component, constraints linked by shared
        outputs: components are independent problems. Built when first needed (a single
        violated constraint needs none)."""
        if self._components is not None:
            return self._components
        found = []
        occ, LM = self.occ_items, self.LM
        left = (1 << len(LM)) - 1
        while left:
            first = left & -left
            members = first
            frontier = LM[first.bit_length() - 1]
            seen = 0
            while frontier:
                low = frontier & -frontier
                frontier ^= low
                seen |= low
                for jbit, _, _, outputs in occ[low.bit_length() - 1]:
                    if not members & jbit:
                        members |= jbit
                        frontier |= outputs & ~seen
            found.append(members)
            left &= ~members
        self._components = found
        return found

    def clauses(self, j: int) -> tuple[int, list[list[int]]]:
        """The outputs and the SAT clauses of constraint j's component: constraint
        `pos . not neg` must be false, so one of its outputs differs from its literal
        (literal 2k + b: output k is b)."""
        members = self.component_of(j)
        found = self._clauses.get(members)
        if found is None:
            outputs = 0
            clauses = []
            m = members
            P, N = self.P, self.N
            while m:
                low = m & -m
                m ^= low
                i = low.bit_length() - 1
                p, q = P[i], N[i]
                outputs |= p | q
                lits = []
                while p:
                    bit = p & -p
                    lits.append(2 * bit.bit_length() - 2)
                    p ^= bit
                while q:
                    bit = q & -q
                    lits.append(2 * bit.bit_length() - 1)
                    q ^= bit
                clauses.append(lits)
            found = self._clauses[members] = (outputs, clauses)
        return found

    def component_of(self, j: int) -> int:
        return next(members for members in self.components if members >> j & 1)

    def original(self, indices: Iterable[int]) -> tuple[int, ...]:
        if self.origin is None:
            return tuple(indices)
        return tuple(self.origin[j] for j in indices)

    def solve(self, start: int, budget: int | None = None, deadline: float | None = None
              ) -> Solution:
        """The safe vector closest to `start` (whose forced outputs must have the values this
        Problem was prepared with), ties broken as documented, within `budget` steps (and,
        live only, before `deadline`, a time.perf_counter() value)."""
        if self.impossible >= 0:
            return Solution(None, 0, 1, "none", steps=self.size, budget=budget,
                            involved=(self.impossible,))
        P, N = self.P, self.N
        violated = [j for j, (p, q) in enumerate(zip(P, N, strict=True))
                    if start & p == p and not start & q]
        steps = len(P)
        if not violated:
            return Solution(start, 0, 1, "unchanged", steps=steps, budget=budget)
        if len(violated) == 1:
            groups = {-1: violated}  # one problem; its component is found only if needed
        else:
            components = self.components
            groups = {}
            for j in violated:
                label = next(c for c, members in enumerate(components) if members >> j & 1)
                groups.setdefault(label, []).append(j)
        flipped = 0
        nodes = 1
        nb = self.nb
        # The cost of changing output k (see _solve_group): D, + O if it switches k on, +
        # 2^(nb-1-k); sums of them order like (distance, orders switched on, priority).
        D = 1 << (nb + 8)
        O = 1 << nb
        cost = [D + (0 if start >> k & 1 else O) + (1 << (nb - 1 - k)) for k in range(nb)]
        for violated in groups.values():
            allowance = None if budget is None else budget - steps
            status, flip, used_nodes, used_steps = _solve_group(self, start, violated, cost,
                                                                allowance, deadline)
            steps += used_steps
            nodes += used_nodes
            if status == "deadline":
                return Solution(None, 0, nodes, "deadline", steps=steps, budget=budget)
            if status == "budget" or (budget is not None and steps > budget):
                return Solution(None, 0, nodes, "budget", steps=steps, budget=budget)
            if status == "none":
                involved = self.original(_bits(self.component_of(violated[0])))
                return Solution(None, 0, nodes, "none", steps=steps, budget=budget,
                                involved=involved)
            flipped |= flip
        return Solution(start ^ flipped, flipped, nodes, "minimal", steps=steps,
                        budget=budget)


class _Proved(Exception):
    """The SAT solver proved that no safe vector exists."""


def _solve_group(problem: Problem, start: int, violated: list[int], cost: list[int],
                 allowance: int | None, deadline: float | None = None
                 ) -> tuple[str, int, int, int]:
    """The cheapest repair of the violated constraints of one component.

    Returns (status, flipped, nodes, steps); status "ok", "none" (proved infeasible),
    "budget" or "deadline". The cost of flipping output k is one integer ordering (distance,
    outputs switched on, priority): D, plus O when k goes 0 -> 1, plus 2^(nb-1-k), so that the
    sum over a set of flips compares exactly like the tie-break (tie_key).

    Branch and bound: a node is a partial assignment (outputs decided flipped or kept, the
    others at their start value); unit propagation over the constraints of each decided
    output follows each decision; the bound adds, to the cost so far, the cheapest flip of
    each violated constraint in a set whose undecided outputs are disjoint (each needs a flip
    of its own); branching is on the violated constraint with the fewest undecided outputs,
    cheapest flip first, each later child keeping the earlier candidates (no vector is visited
    twice). After DIVE_STEPS without any safe vector found, the CDCL solver decides whether
    one exists at all; its model, if any, becomes the bound the search must beat.
    """
    LM, nb = problem.LM, problem.nb
    occ = problem.occ_items
    true_items = problem.true_items
    D = 1 << (nb + 8)
    O = 1 << nb
    steps = 0
    nodes = 0
    viol0 = 0
    for j in violated:
        viol0 |= 1 << j
    INF = 1 << (2 * nb + 20)
    best_g = INF
    best_flip = 0
    cap = DIVE_STEPS if allowance is None else min(DIVE_STEPS, allowance)

    def propagate(v: int, A: int, g: int, viol: int, queue: list[int], kept: int = -1
                  ) -> tuple[int, int, int, int] | None:
        """The assignments in `queue` are already applied; follow their consequences. A kept
        output (`kept`) only matters to the constraints whose literal on it is true."""
        nonlocal steps
        while queue:
            k = queue.pop()
            items = true_items[v >> k & 1][k] if k == kept else occ[k]
            steps += len(items)
            nv = ~v
            na = ~A
            for jbit, pos, neg, lits in items:
                false = lits ^ ((v & pos) | (neg & nv))
                if false:  # not violated
                    if viol & jbit:
                        viol ^= jbit
                    if false & A:
                        continue  # an assigned literal is false: satisfied for good
                    unassigned = lits & na
                    if not unassigned & (unassigned - 1):
                        # Only this undecided, false literal keeps it false: keep that output.
                        # (Marked, not followed: nothing changes value, and following every
                        # kept output's constraints costs more than it prunes.)
                        A |= unassigned
                        na = ~A
                    continue
                unassigned = lits & na
                if not unassigned:
                    return None  # violated, and nothing left to change
                viol |= jbit
                if not unassigned & (unassigned - 1):
                    u = unassigned.bit_length() - 1
                    A |= unassigned
                    na = ~A
                    v ^= unassigned
                    nv = ~v
                    g += cost[u]
                    queue.append(u)
        return v, A, g, viol

    def first_bound() -> None:
        """No safe vector found yet: ask the SAT solver whether there is one at all."""
        nonlocal steps, best_g, best_flip, cap
        outputs, clauses = problem.clauses(violated[0])
        steps += len(clauses)
        left = None if allowance is None else allowance - steps
        sat = solve_sat(_bits(outputs), clauses, phase=start, budget=left, deadline=deadline,
                        clean=True)
        steps += sat.steps
        if sat.status == "budget":
            raise _OutOfBudget
        if sat.status == "deadline":
            raise _OutOfTime
        if sat.status == "unsat":
            raise _Proved
        best_flip = (sat.model ^ start) & outputs
        best_g = sum(cost[k] for k in _bits(best_flip))
        cap = INF if allowance is None else allowance

    def dfs(v: int, A: int, g: int, viol: int) -> None:
        nonlocal best_g, best_flip, nodes, cap, steps
        nodes += 1
        if deadline is not None and not nodes & 15 and time.perf_counter() > deadline:
            raise _OutOfTime
        if steps > cap:
            if allowance is not None and steps > allowance:
                raise _OutOfBudget
            if best_g == INF:
                first_bound()
            else:
                cap = INF if allowance is None else allowance  # it has a bound already
        if not viol:
            if g < best_g:
                best_g = g
                best_flip = v ^ start
            return
        steps += viol.bit_count()  # the bound reads each violated constraint once
        used = 0
        h = 0
        choice = 0
        fewest = 99
        m = viol
        na = ~A
        while m:
            jb = m & -m
            m ^= jb
            cand = LM[jb.bit_length() - 1] & na
            if not cand:
                return  # violated with every output decided: no repair below this node
            size = cand.bit_count()
            if size < fewest:
                fewest, choice = size, cand
            if cand & used:
                continue
            used |= cand
            off = cand & v
            if off:
                h += D + (1 << (nb - off.bit_length()))
            else:
                h += D + O + (1 << (nb - cand.bit_length()))
        if g + h >= best_g:
            return
        order = _bits(choice)
        if len(order) > 1:
            order.sort(key=cost.__getitem__)
        for k in order:
            bit = 1 << k
            if A & bit:  # decided by what keeping the previous candidates implied
                if (v ^ start) & bit:
                    dfs(v, A, g, viol)  # flipped: this is the only child left
                    break
                continue
            child = propagate(v ^ bit, A | bit, g + cost[k], viol, [k])
            if child is not None:
                dfs(*child)
            # the next children keep k as it is
            rest = propagate(v, A | bit, g, viol, [k], k)
            if rest is None:
                break
            v, A, g, viol = rest

    try:
        dfs(start, 0, 0, viol0)
    except _OutOfBudget:
        return "budget", 0, nodes, steps
    except _OutOfTime:
        return "deadline", 0, nodes, steps
    except _Proved:
        return "none", 0, nodes, steps
    if best_g == INF:
        return "none", 0, nodes, steps  # the search ran through every repair: none is safe
    return "ok", best_flip, nodes, steps


def default_budget(scan_period_us: int) -> int:
    """The step budget per scan when the project names none: half the scan period in
    microseconds, as steps. A step costs well under a microsecond (`plchmi bench corrector`
    prints the measured cost), so the search takes a fraction of the period."""
    return max(100, scan_period_us // 2)


def exact_solve(start: int, combined: Masks, unforced: int, budget: int | None = None
                ) -> Solution:
    """The safe vector closest to `start`, ties broken as documented, within `budget` steps
    (a Problem prepared for this one call)."""
    index = first_violated(start, combined)
    if index < 0:
        return Solution(start, 0, 1, "unchanged", steps=len(combined))
    return Problem(combined, unforced, start & ~unforced).solve(start, budget)


STRATEGIES = ("exact", "paper")


def solve(strategy: str, start: int, combined: Masks, unforced: int, f0: int = 0,
          f1: int = 0, budget: int | None = None) -> Solution:
    """One call of either strategy on a problem seen once (the filter keeps Problems)."""
    if strategy == "paper":
        return paper_solve(start, combined, unforced, f0, f1, budget=budget)
    return exact_solve(start, combined, unforced, budget)
