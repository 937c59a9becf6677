"""The scan program's intermediate representation: statements over the image, the history,
the scan's time and the state cells of the runtime objects the program is lowered for.

Why: a rule of the scan (a TON, a TOF ...) is written once, as a lowering into these nodes
(hmi.program.timers), and every form that runs it is printed from them: the Python the
compiled scan runs (hmi.program.python) and the evaluator the reference interpreter runs
(hmi.program.evaluate). A rule is then no longer kept in step by hand between a template
and a method.

The vocabulary is deliberately small: a project's Boolean expression (``Test``, the parsed
tree of hmi.logic.expr), the scan's time, integer and Boolean constants, ``None``, a
subtraction, a comparison ``>=``, a test for ``None``, not/and/or, locals, image slots and
attributes of the objects handed over (``Cell``: a timer's ``since``), assignments and ``if``.
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
class Const:
    """An integer, a Boolean or None (no other constant: hmi.engine.codegen's vocabulary)."""

    value: int | bool | None


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


@dataclass(frozen=True)
class Sub:
    left: Value
    right: Value


@dataclass(frozen=True)
class AtLeast:
    """``left >= right``."""

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


Value = Test | Now | Const | Local | Slot | Cell | Sub | AtLeast | IsNone | Not | And | Or
Target = Local | Slot | Cell

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


Stmt = Assign | If

FALSE = Const(False)
TRUE = Const(True)
NONE = Const(None)
