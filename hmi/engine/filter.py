"""The control filter between the control law and the plant (000 §2.2, 001 §2, 004 §2-5).

Every scan the scan program (hmi.program.constraints) tests each safety constraint on the
candidate output vector (the FOV, or the operator's manual requests) and the uncontrollable
variables Y and applies the policy; this filter's handlers report the violated constraints
with the literals that made them true and — according to the policy — pass the vector
through (`monitor`), latch every output to its safe value (`block`), or correct it
(`correct`): first the simple constraints' set/reset form (004 eq. 6, `mem = not F0 and
FOV or F1`), then the safe vector at minimum Hamming distance for the combined constraints
(:mod:`hmi.engine.solver`); when no safe vector exists, or the search uses up its budget
of steps for the scan, it writes the safe state and says so.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

from hmi.engine.codegen import Vocabulary
from hmi.engine.solver import (
    Problem,
    Solution,
    default_budget,
    free_indices,
    paper_solve,
)
from hmi.logic.expr import History, Image
from hmi.program.constraints import (
    ACTIVE,
    DECISION,
    HANDLERS,
    LATCHED,
    POLICY,
    POLICY_CODES,
    VIOLATIONS,
    ConstraintTable,
    lower_constraints,
    lower_filter,
)
from hmi.program.evaluate import function_evaluator
from hmi.project.model import Constraint, Project

# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------


class Violation(NamedTuple):
    """A constraint true on the candidate vector, with the value of each literal (all true).

    The report's types are NamedTuples, not frozen dataclasses: they are built on every scan
    with a violation, and a NamedTuple is several times cheaper to build."""

    name: str
    kind: str  # simple / combined
    literals: tuple[tuple[str, bool], ...]  # (literal as written, value of the variable)
    description: str = ""


class Change(NamedTuple):
    """An output the filter wrote differently from the candidate vector, and why."""

    output: str
    requested: bool
    written: bool
    by: tuple[str, ...]  # constraint names (or "safe state")
    how: str  # "F0" (forced 0 by a simple constraint), "F1", "combined", "safe state"


class Solver(NamedTuple):
    """The corrector a filter uses: its strategy and its budget per scan (None: the
    project's scan period's default), SafetyFilter's last two arguments."""

    strategy: str
    budget: int | None


class FilterReport(NamedTuple):
    policy: str
    strategy: str
    violations: tuple[Violation, ...] = ()  # on the candidate vector (FOV or manual)
    changes: tuple[Change, ...] = ()
    distance: int = 0  # Hamming distance between the candidate and the written vector
    tested: int = 0  # vectors tested by the solver this scan
    solver_us: float = 0.0  # measured, not deterministic
    fallback: str | None = None  # why the safe state was written instead of a solution
    residual: tuple[str, ...] = ()  # constraints the written vector still violates
    safe_state: bool = False  # the written vector is the project's safe state by decision
    conflicts: tuple[str, ...] = ()  # outputs forced both to 0 and to 1 this scan
    note: str = ""  # how the combined repair was chosen (tie-break), for the operator
    steps: int = 0  # the search's work this scan, in steps (deterministic: the budget's unit)
    budget: int = 0  # the step budget the search ran under
    stopped: str = ""  # "budget" or "deadline": the search was cut short (safe state written)

    @property
    def violated_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.violations)

    @property
    def changed_names(self) -> tuple[str, ...]:
        return tuple(c.output for c in self.changes)

    @property
    def unsafe_written(self) -> bool:
        """The written vector violates a constraint and is not a deliberate safe state."""
        return bool(self.residual) and not self.safe_state


class FilterDecision(NamedTuple):
    """What the filter writes this scan, its report, and (safe blocking) why the engine must
    latch the outputs safe until a fault reset (None: no new latch)."""

    outputs: tuple[bool, ...]
    report: FilterReport
    latch: str | None = None



# --------------------------------------------------------------------------------------------
# Compiled constraints
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CompiledConstraint:
    constraint: Constraint
    pos: int  # outputs that must be 1 for the monomial to be true
    neg: int  # outputs that must be 0
    # How it reads when violated. A monomial is true only when every literal is, so each
    # variable's value is fixed by its literal's polarity: the report is built once, here.
    violation: Violation

    @property
    def preparation(self) -> int:
        """Steps its part of preparing an active set costs: the constraint, and each output
        literal of a combined one (what the exact search's problem is built from)."""
        return 1 if self.simple else 1 + (self.pos | self.neg).bit_count()

    @property
    def name(self) -> str:
        return self.constraint.name

    @property
    def simple(self) -> bool:
        return self.constraint.kind == "simple"


def compile_constraints(table: ConstraintTable) -> list[CompiledConstraint]:
    """The rows of `table` (hmi.program.constraints: the masks the PLC's filter reads too),
    each with its report built once. Which are active and which violated, the scan
    program says (its contexts are tested there, never here)."""
    compiled = []
    for row in table.rows:
        c = row.constraint
        violation = Violation(c.name, c.kind, tuple((str(lit), lit.positive)
                                                    for lit in c.literals), c.description)
        compiled.append(CompiledConstraint(c, row.pos, row.neg, violation))
    return compiled


def pack(values: Iterable[bool]) -> int:
    v = 0
    for k, value in enumerate(values):
        if value:
            v |= 1 << k
    return v


def unpack(v: int, n: int) -> tuple[bool, ...]:
    return tuple(bool(v >> k & 1) for k in range(n))


# --------------------------------------------------------------------------------------------
# The filter
# --------------------------------------------------------------------------------------------

PACKED_CACHE = 4096  # distinct candidate vectors remembered (cleared when full)
CORRECTION_CACHE = 4096  # corrections remembered (cleared when full)
# The caches below hold objects as large as the active constraints: they are bounded by the
# constraints they refer to in all, not by their count (a project whose active set is a new
# one at every scan grew by 36 MB per 100 scans, never emptied). Clearing one changes no
# decision: each is a function of its key.
ACTIVE_SET_CACHE = 50_000  # constraints of the active sets kept prepared, in all (~25 MB)
CORRECTION_CACHE_SIZE = 200_000  # violations and changes of the corrections kept, in all


@dataclass(frozen=True)
class _ActiveSet:
    """The active constraints' f_s0 / f_s1 masks (004 eq. 6), the combined ones for the
    solver, and per output the simple constraints that force it to 0 / to 1."""

    f0: int
    f1: int
    combined: list[tuple[int, int]]
    combined_constraints: tuple[CompiledConstraint, ...]
    forcing0: tuple[tuple[str, ...], ...]
    forcing1: tuple[tuple[str, ...], ...]
    problem: Problem  # the exact search's preparation (empty when nothing is combined)
    # What preparing this set costs, in the budget's steps (a constraint and each output
    # literal of a combined one read once): charged to every scan that corrects with it,
    # prepared anew or kept, so that a budget means the same work either way and the budget
    # bounds the filter's work per scan, not only its search's.
    preparation: int = 0

    @classmethod
    def of(cls, active: Sequence[CompiledConstraint], n: int) -> _ActiveSet:
        simple = [c for c in active if c.simple]
        f0 = f1 = 0
        for c in simple:
            f0 |= c.pos
            f1 |= c.neg
        # A simple constraint has one output literal: positive forces it to 0, negative to 1.
        # Built in one pass over the constraints (not one per output: thousands of each).
        by0: list[list[str]] = [[] for _ in range(n)]
        by1: list[list[str]] = [[] for _ in range(n)]
        for c in simple:
            for mask, names in ((c.pos, by0), (c.neg, by1)):
                while mask:
                    low = mask & -mask
                    names[low.bit_length() - 1].append(c.name)
                    mask ^= low
        forcing0 = tuple(map(tuple, by0))
        forcing1 = tuple(map(tuple, by1))
        combined = tuple(c for c in active if not c.simple)
        masks = [(c.pos, c.neg) for c in combined]
        # Outputs forced by the simple constraints are not free; their values are F1's.
        problem = Problem(masks, ((1 << n) - 1) & ~(f0 | f1), f1)
        return cls(f0, f1, masks, combined, forcing0, forcing1, problem,
                   sum(c.preparation for c in active))


class SafetyFilter:
    """The policy's handlers (what a violated candidate becomes, with its report) and the
    corrector. Which constraints the candidate violates, which are active and what the
    policy does with them are the scan program's (hmi.program.constraints, lowered once:
    `program`): printed by the engine's compiled scan into `violations`, `decide` and
    `active_bits` (handed over by its filter stage, hmi.engine.filter_stage), evaluated here
    until then (a recovery's filter keeps the evaluator's). Stateless between scans except
    for what the engine holds (policy, latch)."""

    # the policy's handlers, and the locals of the constraints' functions (the candidate is
    # a parameter)
    PRINTED = Vocabulary(frozenset(HANDLERS), frozenset(
        local.name for local in (ACTIVE, VIOLATIONS, POLICY, LATCHED, DECISION)))

    def __init__(self, project: Project, slots: Mapping[str, int],
                 step_times: Mapping[str, int] | None = None, strategy: str = "exact",
                 budget: int | None = None):
        self.project = project
        self.strategy = strategy
        # The corrector's budget per scan, in steps: deterministic, so a headless run gives
        # the same trace on any machine (docs/filter.md, "Budget").
        self.budget = budget if budget is not None else default_budget(
            project.scan_period_us)
        # A wall-clock limit on the search, in microseconds, set only by a live runner
        # (hmi.session.live) as a safety net on a slow or loaded machine. Never set in a headless
        # run, a test or a campaign: it cannot change their traces.
        self.wall_limit_us: float | None = None
        self.outputs = tuple(v.name for v in project.outputs)
        self.n = len(self.outputs)
        self.table = lower_constraints(project)
        self.compiled = compile_constraints(self.table)
        self.safe = self.table.safe
        self.all_bits = (1 << self.n) - 1
        # The scan program's functions of the constraints (its lowering, once: the filter
        # stage's, which the PLC's filter block prints too), as its evaluator runs them; the
        # engine's compiled scan hands its own form of them to the stage (FilterStage.bind):
        # the violation word of a candidate, the policy applied to it (calling this filter's
        # handlers), and which constraints are active (bit j: self.compiled[j]).
        self.program = lower_filter(self.table, self)
        times = step_times or {}
        functions = self.program.functions()
        self.violations: Callable[[Image, History, tuple[bool, ...]], int] = \
            function_evaluator(functions["violated"], slots, times)
        self.decide: Callable[..., FilterDecision | None] = function_evaluator(
            functions["decide"], slots, times)
        self.active_bits: Callable[[Image, History], int] = function_evaluator(
            functions["active_bits"], slots, times)
        # What depends only on which constraints are active, built once per active set: a
        # cell has few distinct active sets, and a violation scan should not rebuild them.
        self._by_active: dict[tuple[int, ...], _ActiveSet] = {}
        self._by_active_size = 0  # constraints in the sets kept (ACTIVE_SET_CACHE)
        self._corrections_size = 0  # violations and changes in them (CORRECTION_CACHE_SIZE)
        # Candidate vectors as packed integers: a cell asks for few distinct vectors.
        self._packed: dict[tuple[bool, ...], int] = {}
        # Corrections already found, by (candidate, active constraints' bits): the corrector is a
        # function of these (its search is bounded in steps, not in time, unless a live run
        # set wall_limit_us), and a cell asks for the same repair scan after scan.
        self._corrections: dict[tuple[int, int], tuple[tuple[bool, ...], FilterReport]] = {}
        self.remember = True  # False: every correction searched afresh (the tests' reference)
        # The report of a scan with nothing violated, per policy: immutable, built once.
        self._clean_monitor = FilterReport("monitor", strategy)
        self._clean_block = FilterReport("block", strategy)
        self._clean_correct = FilterReport("correct", strategy)
        self.clean = {"monitor": self._clean_monitor, "block": self._clean_block,
                      "correct": self._clean_correct}

    def active(self, image: Image, history: History) -> list[CompiledConstraint]:
        bits = self.active_bits(image, history)
        return [c for j, c in enumerate(self.compiled) if bits >> j & 1]

    def _violated(self, word: int) -> list[CompiledConstraint]:
        compiled = self.compiled
        found = []
        while word:
            low = word & -word
            found.append(compiled[low.bit_length() - 1])
            word ^= low
        return found

    def apply(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
              latched: bool, word: int | None = None) -> FilterDecision:
        """The filter's decision on the candidate `fov` (`word`: its violation word, when the
        caller has it): the scan program's policy (`decide`), which calls the handlers
        below when it has something to decide. Under `block`, a first violation returns the
        reason to latch (`latched`: the engine's outputs already are) and the engine
        latches; the filter itself holds no state between scans."""
        if word is None:
            word = self.violations(image, history, fov)
        decision = self.decide(image, history, fov, word, POLICY_CODES[policy], latched)
        return FilterDecision(fov, self.clean[policy]) if decision is None else decision

    # -- the policy's handlers (hmi.program.constraints.lower_policy calls them) -------------
    def monitored(self, fov: tuple[bool, ...], word: int) -> FilterDecision:
        """`monitor`, something violated: the candidate passes; the report says what."""
        violated = self._violated(word)
        return FilterDecision(fov, FilterReport(
            "monitor", self.strategy, tuple(c.violation for c in violated),
            residual=tuple(c.name for c in violated)))

    def blocked(self, image: Image, history: History, fov: tuple[bool, ...], word: int,
                latched: bool) -> FilterDecision:
        """`block`, something violated or the outputs latched: the safe state, and on a
        first violation the reason to latch."""
        violated = self._violated(word)
        latch = None
        if violated and not latched:
            first = violated[0].constraint
            why = f": {first.description}" if first.description else ""
            latch = f"safe blocking on {first.name}{why}"
        written, report = self._safe_state(fov, tuple(c.violation for c in violated),
                                           self.active(image, history), "block",
                                           "outputs latched safe")
        return FilterDecision(written, report, latch)

    def corrected(self, image: Image, history: History, fov: tuple[bool, ...], word: int
                  ) -> FilterDecision:
        """`correct`, something violated: the corrector's vector (a correction found before
        for the same candidate and active constraints is given again)."""
        candidate = self._packed.get(fov)
        if candidate is None:
            if len(self._packed) >= PACKED_CACHE:
                self._packed.clear()
            candidate = self._packed[fov] = pack(fov)
        key = None
        if self.remember and self.wall_limit_us is None:
            # (a search cut by wall time depends on the machine: never given again)
            key = (candidate, self.active_bits(image, history))
            found = self._corrections.get(key)
            if found is not None:
                return FilterDecision(*found)
        violations = tuple(c.violation for c in self._violated(word))
        written, report = self._correct(fov, candidate, self.active(image, history),
                                        violations)
        if key is None:
            return FilterDecision(written, report)
        size = 1 + len(report.violations) + len(report.changes)
        if (len(self._corrections) >= CORRECTION_CACHE
                or self._corrections_size + size > CORRECTION_CACHE_SIZE):
            self._corrections.clear()
            self._corrections_size = 0
        self._corrections_size += size
        # Given again, the same decision and report, except that no search ran for it then
        # (solver_us 0; tested and steps still say what finding it took).
        self._corrections[key] = (written, report._replace(solver_us=0.0)
                                  if report.solver_us else report)
        return FilterDecision(written, report)

    def _active_set(self, active: Sequence[CompiledConstraint]) -> _ActiveSet:
        key = tuple(map(id, active))
        found = self._by_active.get(key)
        if found is None:
            if self._by_active_size + len(active) > ACTIVE_SET_CACHE:
                self._by_active.clear()
                self._by_active_size = 0
            found = self._by_active[key] = _ActiveSet.of(active, self.n)
            self._by_active_size += len(active) + 1
        return found

    def _correct(self, fov: tuple[bool, ...], candidate: int,
                 active: Sequence[CompiledConstraint], violations: tuple[Violation, ...]
                 ) -> tuple[tuple[bool, ...], FilterReport]:
        cost = sum(c.preparation for c in active)
        if cost > self.budget and any(not c.simple for c in active):
            # Preparing the corrector's problem alone would cost more than the whole budget:
            # the safe state for this scan, without preparing it (work bounded by the
            # constraints already evaluated, not by the search). Simple constraints alone
            # need no search: their set/reset form is linear, like their evaluation.
            return self._no_solution(fov, violations, active, None, Solution(
                None, 0, 0, "budget", steps=len(active), budget=self.budget), 0.0, cost)
        aset = self._active_set(active)
        f0, f1 = aset.f0, aset.f1
        conflicts = f0 & f1
        if conflicts:
            names = [self.outputs[k] for k in range(self.n) if conflicts >> k & 1]
            report_violations = violations
            return self._safe_state(
                fov, report_violations, active, "correct",
                "simple constraints force " + ", ".join(names) + " both to 0 and to 1",
                conflicts=tuple(names))
        mem = (candidate & ~f0) | f1
        combined = aset.combined
        solution: Solution | None = None
        solver_us = 0.0
        if combined:
            started = time.perf_counter()
            deadline = (None if self.wall_limit_us is None
                        else started + self.wall_limit_us / 1e6)
            left = self.budget - aset.preparation  # the search gets what preparing left
            if left <= 0:
                solution = Solution(None, 0, 0, "budget", steps=0, budget=left)
            elif self.strategy == "paper":
                solution = paper_solve(mem, combined, self.all_bits & ~(f0 | f1), f0, f1,
                                       budget=left, deadline=deadline)
            else:
                assert aset.problem is not None  # prepared whenever there is a combined one
                solution = aset.problem.solve(mem, left, deadline)
            solution = replace(solution, steps=solution.steps + aset.preparation,
                               budget=self.budget)
            solver_us = (time.perf_counter() - started) * 1e6
            if solution.vector is None:
                return self._no_solution(fov, violations, active, aset, solution, solver_us)
            written = solution.vector
        else:
            written = mem
        changes = []
        combined_names = tuple(c.name for c in aset.combined_constraints
                               if mem & c.pos == c.pos and not mem & c.neg)
        for k in range(self.n):
            bit = 1 << k
            if not (written ^ candidate) & bit:
                continue
            if f0 & bit:
                changes.append(Change(self.outputs[k], True, False, aset.forcing0[k], "F0"))
            elif f1 & bit:
                changes.append(Change(self.outputs[k], False, True, aset.forcing1[k], "F1"))
            else:
                changes.append(Change(self.outputs[k], bool(candidate & bit),
                                      bool(written & bit), combined_names, "combined"))
        note = ""
        if solution is not None and solution.flipped:
            note = self._note(solution, combined_names, mem, combined, f0 | f1)
        residual = tuple(c.name for c in active if written & c.pos == c.pos
                         and not written & c.neg)
        return unpack(written, self.n), FilterReport(
            "correct", self.strategy, violations, tuple(changes),
            distance=(written ^ candidate).bit_count(),
            tested=solution.tested if solution else 0, solver_us=solver_us,
            residual=residual, note=note, steps=solution.steps if solution else 0,
            budget=self.budget if solution else 0)

    def _note(self, solution: Solution, names: tuple[str, ...], mem: int,
              combined: Sequence[tuple[int, int]],
              forced: int) -> str:
        """How this strategy chose the repair, in its own words (each states its own rule)."""
        d = solution.distance
        changed = f"{d} output{'s' if d != 1 else ''} changed for {', '.join(names)}"
        if self.strategy != "paper":
            return (f"exact search: {changed}, the fewest possible; among equally close "
                    "vectors, ties go to switching orders off, then to sparing the outputs "
                    f"listed first ({solution.tested} nodes, {solution.steps} steps)")
        free = free_indices(mem, combined, self.all_bits & ~forced)
        order = ", ".join(self.outputs[k] for k in free)
        how = {"closest": "the first safe vector in the paper's enumeration order",
               "farthest": "the memorised farthest vector (the complement of a k-subset: no "
                           "closer vector was safe)",
               "worst case": "the worst case (every free output changed)"}.get(
                   solution.how, solution.how)
        return (f"paper search (Algorithm 1 of 004): {changed}, {how}; no tie-break: among "
                "equally close vectors the first in the paper's order is kept, which changes "
                f"the outputs listed first first (free outputs in order: {order}; "
                f"{solution.tested} vectors tested)")

    def _no_solution(self, fov: tuple[bool, ...], violations: tuple[Violation, ...],
                     active: Sequence[CompiledConstraint], aset: _ActiveSet | None,
                     solution: Solution, solver_us: float, cost: int = 0
                     ) -> tuple[tuple[bool, ...], FilterReport]:
        """The safe state, because no safe vector exists or the search was cut short."""
        if solution.how == "budget" and aset is None:
            why = (f"preparing the {self.strategy} search over the {len(active):,} active "
                   f"constraints would take {cost:,} steps, more than the budget "
                   f"of {self.budget:,}: not searched")
        elif solution.how == "budget":
            why = (f"the {self.strategy} search for the closest safe vector used its budget "
                   f"({solution.steps:,} of {self.budget:,} steps, "
                   f"{aset.preparation if aset else 0:,} of them preparing it) before finding "
                   "it or proving there is none")
        elif solution.how == "deadline":
            limit_ms = (self.wall_limit_us or 0) / 1000
            why = (f"the {self.strategy} search for the closest safe vector reached the live "
                   f"wall-clock limit ({limit_ms:g} ms) before finding it or "
                   "proving there is none")
        else:
            why = "no output vector satisfies every constraint in this situation"
            if solution.involved and aset is not None:
                names = ", ".join(aset.combined_constraints[i].name
                                  for i in solution.involved)
                why += f" ({names} cannot all hold)"
        stopped = solution.how if solution.how in ("budget", "deadline") else ""
        return self._safe_state(fov, violations, active, "correct", why,
                                tested=solution.tested, solver_us=solver_us,
                                steps=solution.steps, stopped=stopped)

    def _safe_state(self, fov: tuple[bool, ...], violations: tuple[Violation, ...],
                    active: Sequence[CompiledConstraint], policy: str, why: str,
                    conflicts: tuple[str, ...] = (), tested: int = 0, solver_us: float = 0.0,
                    steps: int = 0, stopped: str = "") -> tuple[tuple[bool, ...], FilterReport]:
        candidate = pack(fov)
        written = self.safe
        changes = tuple(Change(self.outputs[k], bool(candidate >> k & 1), bool(written >> k & 1),
                               ("safe state",), "safe state")
                        for k in range(self.n) if (candidate ^ written) >> k & 1)
        residual = tuple(c.name for c in active if written & c.pos == c.pos
                         and not written & c.neg)
        fallback = None if policy == "block" else why
        return unpack(written, self.n), FilterReport(
            policy, self.strategy, violations, changes,
            distance=(candidate ^ written).bit_count(), tested=tested, solver_us=solver_us,
            fallback=fallback, residual=residual, safe_state=True, conflicts=conflicts,
            note=why, steps=steps, budget=self.budget if steps else 0, stopped=stopped)

