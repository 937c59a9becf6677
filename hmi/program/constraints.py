"""The safety constraints, lowered once: their table and the tests of the scan program.

A constraint is a monomial that must be false (000 eq. 1-2): violated when every literal is
true. Its literals over the outputs at this scan are two masks over the output vector (POS:
outputs at 1, NEG: outputs at 0); the others (inputs, memories, earlier scans) are its
context, which says whether it is active at this scan. The corrector's search re-tests each
candidate vector against the masks of the active constraints only, so what a filter needs
of the constraints at a scan is the table (:class:`ConstraintTable`: masks, simple or
combined, the safe vector) and which rows are active (:func:`lower_active`, a word of bits).
Both the engine's filter (hmi.engine.filter, the memory key the compiled scan prints) and the
PLC's (hmi.export.filter_pou, the same lowering printed as ST) read them from here.

:func:`lower_violated` is stage 6's first question for the engine: whether a candidate
vector violates any constraint (most scans violate none, and then the filter has nothing
else to do; when one is violated, the filter's own handler reports and decides).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from hmi.logic.expr import And, Literal, Node, Not, Var
from hmi.program import ir
from hmi.project.model import Constraint, Project

CANDIDATE = ir.Local("f")
ACTIVE = ir.Local("b")  # the active word: bit j, row j of the table is active


@dataclass(frozen=True)
class Row:
    """One constraint: its output literals as masks, the rest its context."""

    constraint: Constraint
    pos: int  # outputs that must be 1 for the monomial to be true
    neg: int  # outputs that must be 0
    context: tuple[Literal, ...]  # the literals over Y (none: always active)

    @property
    def simple(self) -> bool:
        return self.constraint.kind == "simple"

    @property
    def context_node(self) -> Node | None:
        """The context as one expression (None: none)."""
        if not self.context:
            return None
        return And(0, tuple(Var(0, lit.name, lit.depth) if lit.positive
                            else Not(0, Var(0, lit.name, lit.depth)) for lit in self.context))

    @property
    def active(self) -> ir.Value:
        """Whether the row is active, as the scan program reads it (literal by literal, in
        the constraint's order)."""
        return ir.all_of(*(_read(lit) for lit in self.context))


@dataclass(frozen=True)
class ConstraintTable:
    """The project's constraints in order (row j: bit j of the active and violation words),
    over `outputs` in order (bit k: output k), and the safe output vector."""

    outputs: tuple[str, ...]
    rows: tuple[Row, ...]
    safe: int


def lower_constraints(project: Project) -> ConstraintTable:
    outputs = tuple(v.name for v in project.outputs)
    index = {name: k for k, name in enumerate(outputs)}
    rows = []
    for c in project.constraints:
        pos = neg = 0
        context = []
        for lit in c.literals:
            if lit.depth == 0 and lit.name in index:
                if lit.positive:
                    pos |= 1 << index[lit.name]
                else:
                    neg |= 1 << index[lit.name]
            else:
                context.append(lit)
        rows.append(Row(c, pos, neg, tuple(context)))
    safe = sum(1 << k for k, v in enumerate(project.outputs) if v.safe)
    return ConstraintTable(outputs, tuple(rows), safe)


@dataclass(frozen=True)
class ActiveWord:
    """The active word's statements: `start` (the rows without a context, always active)
    and, per row, what sets its bit (nothing for a row always active)."""

    start: ir.Stmt
    rows: tuple[tuple[ir.Stmt, ...], ...]

    @property
    def body(self) -> tuple[ir.Stmt, ...]:
        return (self.start, *(stmt for row in self.rows for stmt in row))


def lower_active(table: ConstraintTable) -> ActiveWord:
    """Which rows of `table` are active, into the local ``b`` (bit j: row j). One statement
    per row: a project may have thousands."""
    always = 0
    rows: list[tuple[ir.Stmt, ...]] = []
    for j, row in enumerate(table.rows):
        if row.context:
            rows.append((ir.If(row.active, (ir.Assign(ACTIVE, ir.BitOr(ACTIVE, ir.Bit(j))),)),))
        else:
            always |= 1 << j
            rows.append(())
    return ActiveWord(ir.Assign(ACTIVE, ir.Bits(always)), tuple(rows))


def lower_violated(constraints: Sequence[Constraint], outputs: Sequence[str]) -> ir.Value:
    """True when the candidate vector (the local ``f``, `outputs` in order) violates one of
    `constraints`, tested in order: a literal over an output at this scan reads the
    candidate (``f[k]``), any other the image and the history."""
    index = {name: k for k, name in enumerate(outputs)}
    terms: list[ir.Value] = []
    for c in constraints:
        parts: list[ir.Value] = []
        for lit in c.literals:
            read: ir.Value
            if lit.depth == 0 and lit.name in index:
                read = ir.Item(CANDIDATE, index[lit.name])
                parts.append(read if lit.positive else ir.Not(read))
            else:
                parts.append(_read(lit))
        terms.append(ir.all_of(*parts))
    return ir.any_of(*terms)


def _read(lit: Literal) -> ir.Value:
    read = ir.Test(Var(0, lit.name, lit.depth))
    return read if lit.positive else ir.Not(read)
