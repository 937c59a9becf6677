"""Finding the safe output vector closest (in Hamming distance) to what the program asked for.

Vectors are ints: bit k is output k in the project's declaration order. A combined
constraint, once its context (the literals over uncontrollable variables Y) holds, is a pair
of masks over the outputs: it is violated by v when every output it needs at 1 is 1
(`v & pos == pos`) and every output it needs at 0 is 0 (`v & neg == 0`).

Two strategies give the same minimal distance:

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
* :func:`exact_solve` — branch and bound by iterative deepening over violated constraints: a
  violated monomial is repaired only by flipping one of its output literals, so each node
  branches on the outputs of the first violated constraint only; depth is bounded by the
  distance being tried. All solutions at the minimal depth are collected and the tie-break
  below picks one.

Tie-break (exact): fewest outputs switched on (0 -> 1) — removing an order is safer than
adding one; then, outputs being listed in priority order in the project (first = most
important to keep as asked), the set of changed outputs whose most important member is the
least important (compare the sorted index tuples, larger wins).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

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
    how: str  # "unchanged", "closest", "farthest", "worst case", "minimal", "none"
    paper_fallback: int | None = None  # Fig. 2's last-resort vector, when it is reached

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
                rule: str = "active") -> Solution:
    """Algorithm 1 with the enumeration and memorisation of Fig. 2."""
    tested = 1
    if is_safe(start, combined):
        return Solution(start, 0, tested, "unchanged")
    index = free_indices(start, combined, unforced, rule)
    noc = len(index)
    bits = [1 << i for i in index]
    all_free = sum(bits)
    max_ham = noc
    farthest_solution: int | None = None
    for k in range(1, noc // 2 + 1):
        for ham in paper_subsets(noc, k):
            flip = 0
            for b, on in zip(bits, ham, strict=True):
                if on:
                    flip |= b
            closest = start ^ flip
            tested += 1
            if is_safe(closest, combined):
                return Solution(closest, flip, tested, "closest")
            if max_ham > noc - k:
                farthest = start ^ (all_free ^ flip)
                tested += 1
                if is_safe(farthest, combined):
                    farthest_solution = farthest
                    max_ham = noc - k
    if farthest_solution is not None:
        return Solution(farthest_solution, farthest_solution ^ start, tested, "farthest")
    worst = start ^ all_free
    tested += 1
    if noc and is_safe(worst, combined):
        return Solution(worst, all_free, tested, "worst case")
    fallback = ~f0 & f1  # Fig. 2: mem[i] := NOT F0s[i] AND F1s[i]
    return Solution(None, 0, tested, "none", paper_fallback=fallback)


# --------------------------------------------------------------------------------------------
# Exact branch and bound
# --------------------------------------------------------------------------------------------


def tie_key(flipped: int, start: int) -> tuple:
    """Smaller is preferred: fewer outputs switched on, then spare the high-priority ones."""
    switched_on = (flipped & ~start).bit_count()
    indices = tuple(k for k in range(flipped.bit_length()) if flipped >> k & 1)
    return (switched_on, tuple(-i for i in indices))


def exact_solve(start: int, combined: Masks, unforced: int) -> Solution:
    tested = 1
    if first_violated(start, combined) < 0:
        return Solution(start, 0, tested, "unchanged")
    reachable = 0
    for pos, neg in combined:
        reachable |= pos | neg
    reachable &= unforced
    limit = reachable.bit_count()
    for depth in range(1, limit + 1):
        found: list[int] = []
        seen: set[int] = set()
        stack = [(start, 0)]
        while stack:
            v, flipped = stack.pop()
            index = first_violated(v, combined)
            if index < 0:
                found.append(flipped)
                continue
            if flipped.bit_count() == depth:
                continue
            pos, neg = combined[index]
            candidates = (pos | neg) & unforced & ~flipped
            while candidates:
                bit = candidates & -candidates
                candidates ^= bit
                nxt = flipped | bit
                if nxt in seen:
                    continue
                seen.add(nxt)
                tested += 1
                stack.append((v ^ bit, nxt))
        if found:
            best = min(found, key=lambda f: tie_key(f, start))
            return Solution(start ^ best, best, tested, "minimal")
    return Solution(None, 0, tested, "none")


STRATEGIES = ("exact", "paper")


def solve(strategy: str, start: int, combined: Masks, unforced: int, f0: int = 0,
          f1: int = 0) -> Solution:
    if strategy == "paper":
        return paper_solve(start, combined, unforced, f0, f1)
    return exact_solve(start, combined, unforced)
