"""Assignments and set/reset memories, written once: the lowering of an observer and of an
equation of the control law into the scan program.

A memory keeps its value in its image slot: with reset dominant (an observer, an equation
``reset:`` written first) ``x := NOT reset AND (set OR x)``, with set dominant
``x := set OR (x AND NOT reset)``. The set and reset are read before the slot, as every
form of the scan has always read them.
"""

from __future__ import annotations

from hmi.logic.expr import Node
from hmi.program.ir import And, Assign, Not, Or, Slot, Stmt, Test
from hmi.project.model import Equation, Observer


def lower_assign(slot: int, expr: Node) -> tuple[Stmt, ...]:
    """``x := expr``."""
    return (Assign(Slot(slot), Test(expr)),)


def lower_memory(slot: int, set_: Node, reset: Node, set_dominant: bool) -> tuple[Stmt, ...]:
    """A set/reset memory held in `slot`."""
    x = Slot(slot)
    if set_dominant:
        return (Assign(x, Or((Test(set_), And((x, Not(Test(reset))))))),)
    return (Assign(x, And((Not(Test(reset)), Or((Test(set_), x))))),)


def lower_observer(observer: Observer, slot: int) -> tuple[Stmt, ...]:
    """An observer: an expression, or a memory with reset dominant."""
    if observer.expr is not None:
        return lower_assign(slot, observer.expr.root)
    assert observer.set is not None and observer.reset is not None  # the loader's guarantee
    return lower_memory(slot, observer.set.root, observer.reset.root, set_dominant=False)


def lower_equation(equation: Equation, slot: int) -> tuple[Stmt, ...]:
    """An equation of the control law: an assignment, or a memory (its dominance as
    written)."""
    if equation.expr is not None:
        return lower_assign(slot, equation.expr.root)
    assert equation.set is not None and equation.reset is not None  # the loader's guarantee
    return lower_memory(slot, equation.set.root, equation.reset.root, equation.set_dominant)
