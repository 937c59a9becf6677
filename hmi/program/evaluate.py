"""The reference evaluator of the scan program: the statements of hmi.program.ir turned once
into closures, run on the image, the history and the scan's time (never eval: the project's
expressions through hmi.logic.expr.compile_bool). The compiled scan runs the Python printed
from the same statements (hmi.engine.codegen.print_program); the tests compare the two.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from hmi.logic.expr import History, Image, compile_bool
from hmi.program.ir import (
    And,
    AtLeast,
    Cell,
    Const,
    If,
    IsNone,
    Local,
    Not,
    Now,
    Or,
    Slot,
    Stmt,
    Sub,
    Test,
    Value,
)

Env = dict[str, Any]
ValueFn = Callable[[Image, History, int, Env], Any]
StmtFn = Callable[[Image, History, int, Env], None]
ProgramFn = Callable[[Image, History, int], None]


def evaluator(program: Sequence[Stmt], slots: Mapping[str, int],
              times: Mapping[str, int]) -> ProgramFn:
    """`program` as one function of (image, history, now)."""
    body = _block(program, slots, times)

    def run(image: Image, history: History, now: int) -> None:
        body(image, history, now, {})

    return run


def _block(stmts: Sequence[Stmt], slots: Mapping[str, int],
           times: Mapping[str, int]) -> StmtFn:
    fns = [_stmt(s, slots, times) for s in stmts]

    def block(v: Image, h: History, now: int, env: Env) -> None:
        for fn in fns:
            fn(v, h, now, env)

    return block


def _stmt(stmt: Stmt, slots: Mapping[str, int], times: Mapping[str, int]) -> StmtFn:
    if isinstance(stmt, If):
        test = _value(stmt.test, slots, times)
        then, orelse = _block(stmt.then, slots, times), _block(stmt.orelse, slots, times)

        def if_(v: Image, h: History, now: int, env: Env) -> None:
            (then if test(v, h, now, env) else orelse)(v, h, now, env)

        return if_
    value = _value(stmt.value, slots, times)
    target = stmt.target
    if isinstance(target, Local):
        name = target.name

        def set_local(v: Image, h: History, now: int, env: Env) -> None:
            env[name] = value(v, h, now, env)

        return set_local
    if isinstance(target, Slot):
        index = target.index

        def set_slot(v: Image, h: History, now: int, env: Env) -> None:
            v[index] = value(v, h, now, env)

        return set_slot
    owner, attr = target.owner, target.attr

    def set_cell(v: Image, h: History, now: int, env: Env) -> None:
        setattr(owner, attr, value(v, h, now, env))

    return set_cell


def _value(value: Value, slots: Mapping[str, int], times: Mapping[str, int]) -> ValueFn:
    match value:
        case Test(node=node):
            fn = compile_bool(node, slots, times)
            return lambda v, h, now, env: fn(v, h)
        case Now():
            return lambda v, h, now, env: now
        case Const(value=constant):
            return lambda v, h, now, env: constant
        case Local(name=name):
            return lambda v, h, now, env: env[name]
        case Slot(index=index):
            return lambda v, h, now, env: v[index]
        case Cell(owner=owner, attr=attr):
            return lambda v, h, now, env: getattr(owner, attr)
        case Sub(left=left, right=right):
            a, b = _value(left, slots, times), _value(right, slots, times)
            return lambda v, h, now, env: a(v, h, now, env) - b(v, h, now, env)
        case AtLeast(left=left, right=right):
            a, b = _value(left, slots, times), _value(right, slots, times)
            return lambda v, h, now, env: a(v, h, now, env) >= b(v, h, now, env)
        case IsNone(operand=operand):
            a = _value(operand, slots, times)
            return lambda v, h, now, env: a(v, h, now, env) is None
        case Not(operand=operand):
            a = _value(operand, slots, times)
            return lambda v, h, now, env: not a(v, h, now, env)
        case And(operands=operands):
            fns = [_value(o, slots, times) for o in operands]
            return lambda v, h, now, env: all(fn(v, h, now, env) for fn in fns)
        case Or(operands=operands):
            fns = [_value(o, slots, times) for o in operands]
            return lambda v, h, now, env: any(fn(v, h, now, env) for fn in fns)
    raise TypeError(f"not a value of the scan program: {value!r}")
