"""The scan program's intermediate representation: statements over the image, the history,
the scan's time and number, and the state cells of the runtime objects the program is
lowered for.

Why: a rule of the scan (a TON, a diagnoser's transition, a GRAFCET's enabling ...) is
written once, as a lowering into these nodes (hmi.program.timers, diagnosers, grafcet ...),
and every form that runs it is printed from them: the Python the compiled scan runs
(hmi.engine.codegen.print_program) and the closures of the reference evaluator
(hmi.program.evaluate). A rule is then no longer kept in step by hand between a template
and a method.

The vocabulary is deliberately small: a project's Boolean expression (``Test``, the parsed
tree of hmi.logic.expr), the scan's time and number, integer and Boolean constants and
``None``, words of bits (a constant word, one bit, their or), ``+``, ``-``, comparisons, a
test for ``None``, not/and/or, locals, image slots, attributes of the runtime objects handed
over (``Cell``: a timer's ``since``), items of a sequence, assignments, ``if`` and
``switch``. What happens rarely and needs the runtime's bookkeeping (a diagnoser entering a
state builds the record the snapshot shows, a GRAFCET firing computes its new steps) is an
explicit call of a handler object's method (``Call``, as a value, or ``Do`` as a
statement).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hmi.logic.expr import Node

# -- values ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Test:
    """A project's Boolean expression, read on the image and the history."""

    node: Node


@dataclass(frozen=True)
class Now:
    """The scan's time (microseconds)."""


@dataclass(frozen=True)
class ScanNumber:
    """The scan's number (1 for the first)."""


@dataclass(frozen=True)
class TheImage:
    """The image itself (a handler's argument)."""


@dataclass(frozen=True)
class TheHistory:
    """The history itself (a handler's argument)."""


@dataclass(frozen=True)
class Const:
    """An integer, a Boolean, None or a tuple of integers (no other constant:
    hmi.engine.codegen's vocabulary)."""

    value: int | bool | tuple[int, ...] | None


@dataclass(frozen=True)
class Local:
    name: str


@dataclass(frozen=True)
class Slot:
    """A slot of the image, read or written."""

    index: int


@dataclass(frozen=True, eq=False)
class Cell:
    """An attribute of a runtime object the program is lowered for (its state lives there:
    a snapshot, a capture and the stage objects read it)."""

    owner: Any
    attr: str


@dataclass(frozen=True, eq=False)
class Ref:
    """A runtime object handed over as it is (a table, a constant the program compares
    with by identity)."""

    obj: Any


@dataclass(frozen=True)
class Item:
    """``base[index]``: an item of a sequence, read or (a list) written."""

    base: Value
    index: int


@dataclass(frozen=True)
class Field:
    """``base.name``: a field of a record (hmi.engine.compiled's frame reads its own
    records', a diagnosis's or the last news'; a slotted record's field is read as fast as a
    tuple's item, a named tuple's item on CPython 3.11 several times slower)."""

    base: Value
    name: str


@dataclass(frozen=True)
class Tuple:
    """A tuple of values (a vector of outputs)."""

    items: tuple[Value, ...]


@dataclass(frozen=True)
class Bits:
    """A word of bits (bit k says one thing of the k-th: a constraint active ...), as an
    integer. A project's thousands of constraints make it thousands of digits: the Python
    form is handed it whole; the PLC's is a bit string (DWORD, LWORD)."""

    value: int


@dataclass(frozen=True)
class Bit:
    """The word with bit `index` alone set (``1 << index``)."""

    index: int


@dataclass(frozen=True)
class BitOr:
    """The bits set in `left` or in `right` (two words)."""

    left: Value
    right: Value


@dataclass(frozen=True)
class Add:
    left: Value
    right: Value


@dataclass(frozen=True)
class Sub:
    left: Value
    right: Value


COMPARISONS = ("==", "!=", "<", "<=", ">", ">=", "is")


@dataclass(frozen=True)
class Compare:
    """``left op right``, op one of COMPARISONS (``is``: the same object)."""

    op: str
    left: Value
    right: Value


@dataclass(frozen=True)
class IsNone:
    operand: Value


@dataclass(frozen=True)
class Not:
    operand: Value


@dataclass(frozen=True)
class And:
    """Operands evaluated in order, the first false one ending it (Python's, ST's AND_THEN)."""

    operands: tuple[Value, ...]


@dataclass(frozen=True)
class Or:
    """Operands evaluated in order, the first true one ending it."""

    operands: tuple[Value, ...]


@dataclass(frozen=True, eq=False)
class Call:
    """A handler's method called with `args`: a rare event, or the runtime's bookkeeping.
    Its value is what the method returns."""

    owner: Any
    method: str
    args: tuple[Value, ...] = ()


@dataclass(frozen=True)
class Apply:
    """The function `function` holds (a local the frame read from a cell: the compiled
    scan's ``core``, whoever replaces it) called with `args`. Why not a Call of the cell's
    owner: CPython 3.11 looks up an object's attribute that is not a method the slow way
    at every call (some 100 instructions), a local's function it calls straight."""

    function: Value
    args: tuple[Value, ...] = ()


Value = (Test | Now | ScanNumber | TheImage | TheHistory | Const | Local | Slot | Cell | Ref
         | Item | Field | Tuple | Bits | Bit | BitOr | Add | Sub | Compare | IsNone | Not | And | Or
         | Call | Apply)
Target = Local | Slot | Cell | Item

# -- statements ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Assign:
    target: Target
    value: Value


@dataclass(frozen=True)
class If:
    test: Value
    then: tuple[Stmt, ...]
    orelse: tuple[Stmt, ...] = ()


@dataclass(frozen=True)
class Do:
    """A call whose value is not used."""

    call: Call | Apply


@dataclass(frozen=True)
class Switch:
    """The statements of the case whose integer equals `value` (at most one), else
    `default`."""

    value: Value
    cases: tuple[tuple[int, tuple[Stmt, ...]], ...]
    default: tuple[Stmt, ...] = ()


@dataclass(frozen=True)
class Return:
    """Leave the function with `value` (hmi.engine.compiled's frames only: a stage's
    program runs to its end)."""

    value: Value


@dataclass(frozen=True, eq=False)
class Try:
    """`body`; an exception of one of the `handlers`' classes (tried in order) is bound to
    the local named there and its statements run instead of the rest of `body`. Only the
    engine's frame around a mode's program uses it (what fails there is the plant's I/O or
    a stage's bug: the engine's own handlers say what to do)."""

    body: tuple[Stmt, ...]
    handlers: tuple[tuple[type[BaseException], str, tuple[Stmt, ...]], ...]


Stmt = Assign | If | Do | Switch | Return | Try

FALSE = Const(False)
TRUE = Const(True)
NONE = Const(None)


def at_least(left: Value, right: Value) -> Compare:
    return Compare(">=", left, right)


def all_of(*operands: Value) -> Value:
    """The conjunction of `operands` (TRUE when none; the operand itself when one)."""
    if not operands:
        return TRUE
    return operands[0] if len(operands) == 1 else And(tuple(operands))


def any_of(*operands: Value) -> Value:
    if not operands:
        return FALSE
    return operands[0] if len(operands) == 1 else Or(tuple(operands))


def if_chain(branches: list[tuple[Value, tuple[Stmt, ...]]],
             orelse: tuple[Stmt, ...] = ()) -> tuple[Stmt, ...]:
    """``if a: ... elif b: ... else: ...`` as nested Ifs (printed as elif)."""
    result = orelse
    for test, then in reversed(branches):
        result = (If(test, then, result),)
    return result


@dataclass(frozen=True)
class Function:
    """A program as one function: `params` (named as its locals; ``v``, ``h``, ``now`` and
    ``scan`` are the image, the history, the scan's time and number), `body`, and the
    value it returns (None: nothing)."""

    name: str
    params: tuple[str, ...]
    body: tuple[Stmt, ...]
    result: Value | None = None
