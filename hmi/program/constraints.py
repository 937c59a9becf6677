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

:func:`lower_violations` is stage 6's first question: which constraints a candidate vector
violates, as a word (0 on most scans, and then the filter has nothing else to do);
:func:`lower_policy` what the policy does with that word, calling a handler for what it
decides (the engine's SafetyFilter builds the report and runs its corrector; the PLC's
block latches or runs its search). The engine prints them as ``violated`` and ``decide``,
the PLC's filter block as its word ``Violations`` and the IF on its ``Policy``. The three
are lowered together once per filter (:func:`lower_filter`, :class:`FilterProgram`): the
filter stage owns them (hmi.engine.filter_stage), and the PLC's block prints that stage's.
"""

from __future__ import annotations

from dataclasses import dataclass

from hmi.logic.expr import And, Literal, Node, Not, Var
from hmi.program import ir
from hmi.project.model import Constraint, Project

CANDIDATE = ir.Local("f")
ACTIVE = ir.Local("b")  # the active word: bit j, row j of the table is active
VIOLATIONS = ir.Local("w")  # the violation word: bit j, row j is violated by the candidate
POLICY = ir.Local("p")  # the policy's code (POLICY_CODES)
LATCHED = ir.Local("latched")  # the outputs are latched safe (the block policy's latch)
DECISION = ir.Local("d")  # the handler's decision (None: the candidate passes, clean)

# The policies as the program compares them (the PLC's filter reads any other value of its
# Policy input as `correct`: a wrong setting never passes unsafe orders through)
MONITOR, BLOCK, CORRECT = 0, 1, 2
POLICY_CODES = {"monitor": MONITOR, "block": BLOCK, "correct": CORRECT}
# What the policy program calls on its handler (the engine's SafetyFilter; the PLC's filter
# block has their ST versions, hmi.export.filter_pou)
HANDLERS = ("blocked", "corrected", "monitored")


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


def lower_violations(table: ConstraintTable) -> tuple[ir.Stmt, ...]:
    """Which rows of `table` the candidate vector (the local ``f``: bit k or item k, output
    k) violates, into the local ``w`` (bit j: row j), one statement per row: a row is
    violated when every literal is true, tested in the constraint's order (a literal over an
    output at this scan reads the candidate, any other the image and the history). Stage
    6's first question: ``w`` is 0 on most scans, and then the filter has nothing else to
    do."""
    index = {name: k for k, name in enumerate(table.outputs)}
    body: list[ir.Stmt] = [ir.Assign(VIOLATIONS, ir.Const(0))]
    for j, row in enumerate(table.rows):
        parts: list[ir.Value] = []
        for lit in row.constraint.literals:
            if lit.depth == 0 and lit.name in index:
                read = ir.Item(CANDIDATE, index[lit.name])
                parts.append(read if lit.positive else ir.Not(read))
            else:
                parts.append(_read(lit))
        body.append(ir.If(ir.all_of(*parts),
                          (ir.Assign(VIOLATIONS, ir.BitOr(VIOLATIONS, ir.Bit(j))),)))
    return tuple(body)


def lower_policy(handler: object) -> tuple[ir.Stmt, ...]:
    """The policy (``p``) applied to the violation word ``w``, into the local ``d``: the
    handler's decision, or None when the candidate passes as it is. `block` latches the
    outputs safe on a violation and keeps them so (``latched``) until a fault reset;
    `correct` (any code but monitor and block) hands a violated candidate to the corrector
    (the rare, expensive part: a handler); `monitor` passes it and says what it violates.
    The handler is called only when it has something to decide; its methods are HANDLERS,
    called with the image, the history, the candidate and the word."""
    def call(method: str, *args: ir.Value) -> ir.Call:
        return ir.Call(handler, method, args)

    violated = ir.Compare("!=", VIOLATIONS, ir.Const(0))
    image, history = ir.TheImage(), ir.TheHistory()
    return (
        ir.Assign(DECISION, ir.NONE),
        *ir.if_chain([
            (ir.Compare("==", POLICY, ir.Const(BLOCK)),
             (ir.If(ir.Or((LATCHED, violated)), (ir.Assign(DECISION, call(
                 "blocked", image, history, CANDIDATE, VIOLATIONS, LATCHED)),)),)),
            (ir.And((ir.Compare("!=", POLICY, ir.Const(MONITOR)), violated)),
             (ir.Assign(DECISION, call("corrected", image, history, CANDIDATE, VIOLATIONS)),)),
            (violated, (ir.Assign(DECISION, call("monitored", CANDIDATE, VIOLATIONS)),)),
        ]),
    )


def _read(lit: Literal) -> ir.Value:
    read = ir.Test(Var(0, lit.name, lit.depth))
    return read if lit.positive else ir.Not(read)


@dataclass(frozen=True)
class FilterProgram:
    """The safety filter's lowering, once: its table and the statements of its three
    questions. The engine's filter stage prints or evaluates them as its functions
    (:meth:`functions`: ``violated``, ``decide``, ``active_bits``); the PLC's filter block
    prints the same statements (hmi.export.filter_pou), its handler's calls as ST."""

    table: ConstraintTable
    active: ActiveWord  # which rows are active (lower_active)
    violations: tuple[ir.Stmt, ...]  # the candidate's violation word (lower_violations)
    policy: tuple[ir.Stmt, ...]  # the policy, calling the handler (lower_policy)

    def functions(self) -> dict[str, ir.Function]:
        """The three questions as the scan program's functions, by name."""
        return {"violated": _violated(self.violations), "decide": _decide(self.policy),
                "active_bits": _active(self.active.body)}


def lower_filter(table: ConstraintTable, handler: object) -> FilterProgram:
    """The filter of `table` whose policy calls `handler`'s HANDLERS."""
    return FilterProgram(table, lower_active(table), lower_violations(table),
                         lower_policy(handler))


def _violated(body: tuple[ir.Stmt, ...]) -> ir.Function:
    return ir.Function("violated", ("v", "h", "f"), body, VIOLATIONS)


def _decide(body: tuple[ir.Stmt, ...]) -> ir.Function:
    return ir.Function("decide", ("v", "h", "f", "w", "p", "latched"), body, DECISION)


def _active(body: tuple[ir.Stmt, ...]) -> ir.Function:
    return ir.Function("active_bits", ("v", "h"), body, ACTIVE)


def violations_function(table: ConstraintTable) -> ir.Function:
    """``violated(v, h, f) -> w``: the violation word of the candidate `f` (the outputs in
    order), :func:`lower_violations`."""
    return _violated(lower_violations(table))


def policy_function(handler: object) -> ir.Function:
    """``decide(v, h, f, w, p, latched) -> decision or None``: :func:`lower_policy`,
    calling `handler`'s methods."""
    return _decide(lower_policy(handler))


def active_function(table: ConstraintTable) -> ir.Function:
    """``active_bits(v, h) -> b``: which rows of `table` are active, :func:`lower_active`."""
    return _active(lower_active(table).body)
