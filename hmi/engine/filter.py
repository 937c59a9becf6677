"""The control filter between the control law and the plant (000 §2.2, 001 §2, 004 §2-5).

Every scan it evaluates each safety constraint on the candidate output vector (the FOV, or
the operator's manual requests) and the uncontrollable variables Y, reports the violated
constraints with the literals that made them true, and — according to the policy — passes
the vector through (`monitor`), latches every output to its safe value (`block`), or corrects
it (`correct`): first the simple constraints' set/reset form (004 eq. 6, `mem = not F0 and
FOV or F1`), then the safe vector at minimum Hamming distance for the combined constraints
(:mod:`hmi.engine.solver`); when no safe vector exists it writes the safe state and says so.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

from hmi.engine.solver import Solution, is_safe, solve
from hmi.logic.expr import And, BoolFn, Literal, Not, Var, compile_bool
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


# --------------------------------------------------------------------------------------------
# Compiled constraints
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CompiledConstraint:
    constraint: Constraint
    context: BoolFn | None  # the product of the literals over Y (None: always true)
    pos: int  # outputs that must be 1 for the monomial to be true
    neg: int  # outputs that must be 0
    literal_slots: tuple[tuple[Literal, int], ...]

    @property
    def name(self) -> str:
        return self.constraint.name

    @property
    def simple(self) -> bool:
        return self.constraint.kind == "simple"


def compile_constraints(project: Project, slots, step_times=None) -> list[CompiledConstraint]:
    index = {v.name: k for k, v in enumerate(project.outputs)}
    compiled = []
    for c in project.constraints:
        pos = neg = 0
        context_nodes = []
        for lit in c.literals:
            if lit.depth == 0 and lit.name in index:
                bit = 1 << index[lit.name]
                if lit.positive:
                    pos |= bit
                else:
                    neg |= bit
            else:
                context_nodes.append(lit)
        context = None
        if context_nodes:
            nodes = tuple(Var(0, lit.name, lit.depth) if lit.positive
                          else Not(0, Var(0, lit.name, lit.depth)) for lit in context_nodes)
            context = compile_bool(And(0, nodes), slots, step_times)
        compiled.append(CompiledConstraint(
            c, context, pos, neg, tuple((lit, slots[lit.name]) for lit in c.literals)))
    return compiled


def pack(values) -> int:
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


class SafetyFilter:
    """Stateless between scans except for what the engine holds (policy, latch)."""

    def __init__(self, project: Project, slots, step_times=None, strategy: str = "exact"):
        self.project = project
        self.strategy = strategy
        self.outputs = tuple(v.name for v in project.outputs)
        self.n = len(self.outputs)
        self.compiled = compile_constraints(project, slots, step_times)
        self.safe = pack(v.safe for v in project.outputs)
        self.all_bits = (1 << self.n) - 1
        self._readers: dict[str, tuple] = {}  # constraint -> how to read each literal

    # The engine's output stage.
    def __call__(self, engine, fov: tuple[bool, ...]):
        return self.apply(engine, fov)

    def active(self, image, history) -> list[CompiledConstraint]:
        return [c for c in self.compiled if c.context is None or c.context(image, history)]

    def apply(self, engine, fov: tuple[bool, ...]):
        image, history = engine.image, engine.history
        candidate = pack(fov)
        active = self.active(image, history)
        violated = [c for c in active if candidate & c.pos == c.pos and not candidate & c.neg]
        violations = tuple(self._violation(c, image, history, candidate) for c in violated)
        policy = engine.policy
        if policy == "monitor":
            report = FilterReport(policy, self.strategy, violations,
                                  residual=tuple(c.name for c in violated))
            return fov, report
        if policy == "block":
            if violated and not engine.latched:
                first = violated[0].constraint
                why = f": {first.description}" if first.description else ""
                engine.latch_safe("filter", f"safe blocking on {first.name}{why}")
            if engine.latched:
                return self._safe_state(fov, violations, active, policy, "outputs latched safe")
            return fov, FilterReport(policy, self.strategy, violations)
        return self._correct(fov, candidate, active, violations)

    def _correct(self, fov, candidate: int, active, violations):
        if not violations:
            # Common case: the candidate violates nothing, so it is written unchanged (a
            # conflict between simple constraints would show as a violation).
            return fov, FilterReport("correct", self.strategy)
        f0 = f1 = 0
        for c in active:
            if c.simple:
                f0 |= c.pos
                f1 |= c.neg
        conflicts = f0 & f1
        if conflicts:
            names = [self.outputs[k] for k in range(self.n) if conflicts >> k & 1]
            report_violations = violations
            return self._safe_state(
                fov, report_violations, active, "correct",
                "simple constraints force " + ", ".join(names) + " both to 0 and to 1",
                conflicts=tuple(names))
        mem = (candidate & ~f0) | f1
        combined = [(c.pos, c.neg) for c in active if not c.simple]
        solution: Solution | None = None
        solver_us = 0.0
        if combined:
            started = time.perf_counter()
            solution = solve(self.strategy, mem, combined, self.all_bits & ~(f0 | f1), f0, f1)
            solver_us = (time.perf_counter() - started) * 1e6
            if solution.vector is None:
                return self._safe_state(
                    fov, violations, active, "correct",
                    "no output vector satisfies every constraint in this situation",
                    tested=solution.tested, solver_us=solver_us)
            written = solution.vector
        else:
            written = mem
        changes = []
        combined_names = tuple(c.name for c in active if not c.simple
                               and mem & c.pos == c.pos and not mem & c.neg)
        by = {}
        for c in active:
            if c.simple:
                by.setdefault((c.pos or c.neg, "F0" if c.pos else "F1"), []).append(c.name)
        for k in range(self.n):
            bit = 1 << k
            if not (written ^ candidate) & bit:
                continue
            if f0 & bit:
                names = tuple(n for (mask, how), ns in by.items() if how == "F0" and mask & bit
                              for n in ns)
                changes.append(Change(self.outputs[k], True, False, names, "F0"))
            elif f1 & bit:
                names = tuple(n for (mask, how), ns in by.items() if how == "F1" and mask & bit
                              for n in ns)
                changes.append(Change(self.outputs[k], False, True, names, "F1"))
            else:
                changes.append(Change(self.outputs[k], bool(candidate & bit),
                                      bool(written & bit), combined_names, "combined"))
        note = ""
        if solution is not None and solution.flipped:
            note = (f"{self.strategy} search: {solution.distance} output"
                    f"{'s' if solution.distance != 1 else ''} changed for "
                    f"{', '.join(combined_names)} ({solution.how}, {solution.tested} vectors "
                    "tested; ties go to switching orders off, then to sparing the outputs "
                    "listed first)")
        residual = tuple(c.name for c in active if written & c.pos == c.pos
                         and not written & c.neg)
        return unpack(written, self.n), FilterReport(
            "correct", self.strategy, violations, tuple(changes),
            distance=(written ^ candidate).bit_count(),
            tested=solution.tested if solution else 0, solver_us=solver_us,
            residual=residual, note=note)

    def _safe_state(self, fov, violations, active, policy: str, why: str,
                    conflicts: tuple[str, ...] = (), tested: int = 0, solver_us: float = 0.0):
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
            note=why)

    def _violation(self, c: CompiledConstraint, image, history, candidate: int) -> Violation:
        readers = self._readers.get(c.name)
        if readers is None:
            out_index = {name: k for k, name in enumerate(self.outputs)}
            readers = self._readers[c.name] = tuple(
                (str(lit), out_index.get(lit.name, -1) if lit.depth == 0 else -1, lit.depth,
                 slot) for lit, slot in c.literal_slots)
        values = tuple(
            (text, bool(candidate >> out & 1) if out >= 0 else
             bool(image[slot]) if depth == 0 else bool(history[depth - 1][slot]))
            for text, out, depth, slot in readers)
        return Violation(c.name, c.constraint.kind, values, c.constraint.description)


def safe_for_all(vector: tuple[bool, ...], compiled, image, history) -> bool:
    v = pack(vector)
    active = [c for c in compiled if c.context is None or c.context(image, history)]
    return is_safe(v, [(c.pos, c.neg) for c in active])
