"""The reference evaluator of the scan program: the statements of hmi.program.ir turned once
into closures, run on the image, the history, the scan's time and number (never eval: the
project's expressions through hmi.logic.expr.compile_bool). The compiled scan runs the
Python printed from the same statements (hmi.engine.codegen.print_program); the tests
compare the two.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from hmi.logic.expr import History, Image, compile_bool
from hmi.program.ir import (
    Add,
    And,
    Apply,
    Assign,
    Bit,
    BitOr,
    Bits,
    Call,
    Cell,
    Compare,
    Const,
    Do,
    Field,
    Function,
    If,
    IsNone,
    Item,
    Local,
    Not,
    Now,
    Or,
    Ref,
    Return,
    ScanNumber,
    Slot,
    Stmt,
    Sub,
    Switch,
    Test,
    TheHistory,
    TheImage,
    Try,
    Tuple,
    Value,
)

Env = dict[str, Any]
ValueFn = Callable[[Image, History, int, int, Env], Any]
StmtFn = Callable[[Image, History, int, int, Env], None]
ProgramFn = Callable[..., None]  # (image, history, now, scan=0)

_OPERATORS: dict[str, Callable[[Any, Any], Any]] = {
    "==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le,
    ">": operator.gt, ">=": operator.ge, "is": operator.is_}


def evaluator(program: Sequence[Stmt], slots: Mapping[str, int],
              times: Mapping[str, int]) -> ProgramFn:
    """`program` as one function of (image, history, now, scan); keyword arguments are its
    locals' first values (a lowering's parameters)."""
    body = _block(program, slots, times)

    def run(image: Image, history: History, now: int, scan: int = 0, **env: Any) -> None:
        body(image, history, now, scan, env)

    return run


class _Returned(Exception):
    """A Return statement leaving the function (its value in `value`)."""

    def __init__(self, value: Any):
        super().__init__()
        self.value = value


def function_evaluator(function: Function, slots: Mapping[str, int],
                       times: Mapping[str, int]) -> Callable[..., Any]:
    """`function` as a Python callable taking its parameters, in order."""
    body = _block(function.body, slots, times)
    result = _value(function.result, slots, times) if function.result is not None else None
    params = function.params
    special = {"v", "h", "now", "scan"}

    def run(*args: Any) -> Any:
        bound = dict(zip(params, args, strict=True))
        env = {name: value for name, value in bound.items() if name not in special}
        v, h = bound.get("v", []), bound.get("h", ())
        now, scan = bound.get("now", 0), bound.get("scan", 0)
        try:
            body(v, h, now, scan, env)
        except _Returned as returned:
            return returned.value
        return None if result is None else result(v, h, now, scan, env)

    return run


def value_evaluator(value: Value, slots: Mapping[str, int], times: Mapping[str, int]
                    ) -> Callable[..., Any]:
    """One value of the program as a function of (image, history, now, scan)."""
    fn = _value(value, slots, times)

    def run(image: Image, history: History, now: int = 0, scan: int = 0) -> Any:
        return fn(image, history, now, scan, {})

    return run


def _block(stmts: Sequence[Stmt], slots: Mapping[str, int],
           times: Mapping[str, int]) -> StmtFn:
    fns = [_stmt(s, slots, times) for s in stmts]

    def block(v: Image, h: History, now: int, scan: int, env: Env) -> None:
        for fn in fns:
            fn(v, h, now, scan, env)

    return block


def _stmt(stmt: Stmt, slots: Mapping[str, int], times: Mapping[str, int]) -> StmtFn:
    if isinstance(stmt, If):
        test = _value(stmt.test, slots, times)
        then, orelse = _block(stmt.then, slots, times), _block(stmt.orelse, slots, times)

        def if_(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            (then if test(v, h, now, scan, env) else orelse)(v, h, now, scan, env)

        return if_
    if isinstance(stmt, Switch):
        selector = _value(stmt.value, slots, times)
        cases = {key: _block(body, slots, times) for key, body in stmt.cases}
        default = _block(stmt.default, slots, times)

        def switch(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            cases.get(selector(v, h, now, scan, env), default)(v, h, now, scan, env)

        return switch
    if isinstance(stmt, Return):
        returned = _value(stmt.value, slots, times)

        def return_(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            raise _Returned(returned(v, h, now, scan, env))

        return return_
    if isinstance(stmt, Try):
        body = _block(stmt.body, slots, times)
        handlers = [(kind, name, _block(block, slots, times))
                    for kind, name, block in stmt.handlers]

        def try_(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            try:
                body(v, h, now, scan, env)
            except _Returned:
                raise
            except Exception as exc:
                for kind, name, handler in handlers:
                    if isinstance(exc, kind):
                        env[name] = exc
                        handler(v, h, now, scan, env)
                        return
                raise

        return try_
    if isinstance(stmt, Do):
        call = _value(stmt.call, slots, times)

        def do(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            call(v, h, now, scan, env)

        return do
    assert isinstance(stmt, Assign)
    value = _value(stmt.value, slots, times)
    target = stmt.target
    if isinstance(target, Local):
        name = target.name

        def set_local(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            env[name] = value(v, h, now, scan, env)

        return set_local
    if isinstance(target, Slot):
        index = target.index

        def set_slot(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            v[index] = value(v, h, now, scan, env)

        return set_slot
    if isinstance(target, Item):
        base, key = _value(target.base, slots, times), target.index

        def set_item(v: Image, h: History, now: int, scan: int, env: Env) -> None:
            base(v, h, now, scan, env)[key] = value(v, h, now, scan, env)

        return set_item
    owner, attr = target.owner, target.attr

    def set_cell(v: Image, h: History, now: int, scan: int, env: Env) -> None:
        setattr(owner, attr, value(v, h, now, scan, env))

    return set_cell


def _value(value: Value, slots: Mapping[str, int], times: Mapping[str, int]) -> ValueFn:
    match value:
        case Test(node=node):
            fn = compile_bool(node, slots, times)
            return lambda v, h, now, scan, env: fn(v, h)
        case Now():
            return lambda v, h, now, scan, env: now
        case ScanNumber():
            return lambda v, h, now, scan, env: scan
        case TheImage():
            return lambda v, h, now, scan, env: v
        case TheHistory():
            return lambda v, h, now, scan, env: h
        case Const(value=constant) | Ref(obj=constant):
            return lambda v, h, now, scan, env: constant
        case Local(name=name):
            return lambda v, h, now, scan, env: env[name]
        case Slot(index=index):
            return lambda v, h, now, scan, env: v[index]
        case Cell(owner=owner, attr=attr):
            return lambda v, h, now, scan, env: getattr(owner, attr)
        case Item(base=base, index=index):
            b = _value(base, slots, times)
            return lambda v, h, now, scan, env: b(v, h, now, scan, env)[index]
        case Field(base=base, name=name):
            r = _value(base, slots, times)
            return lambda v, h, now, scan, env: getattr(r(v, h, now, scan, env), name)
        case Tuple(items=items):
            fns = [_value(i, slots, times) for i in items]
            return lambda v, h, now, scan, env: tuple([fn(v, h, now, scan, env) for fn in fns])
        case Bits(value=bits):
            return lambda v, h, now, scan, env: bits
        case Bit(index=index):
            word = 1 << index
            return lambda v, h, now, scan, env: word
        case BitOr(left=left, right=right):
            a, b = _value(left, slots, times), _value(right, slots, times)
            return lambda v, h, now, scan, env: (a(v, h, now, scan, env)
                                                 | b(v, h, now, scan, env))
        case Add(left=left, right=right) | Sub(left=left, right=right):
            a, b = _value(left, slots, times), _value(right, slots, times)
            if isinstance(value, Add):
                return lambda v, h, now, scan, env: (a(v, h, now, scan, env)
                                                     + b(v, h, now, scan, env))
            return lambda v, h, now, scan, env: (a(v, h, now, scan, env)
                                                 - b(v, h, now, scan, env))
        case Compare(op=op, left=left, right=right):
            a, b = _value(left, slots, times), _value(right, slots, times)
            compare = _OPERATORS[op]
            return lambda v, h, now, scan, env: compare(a(v, h, now, scan, env),
                                                        b(v, h, now, scan, env))
        case IsNone(operand=operand):
            a = _value(operand, slots, times)
            return lambda v, h, now, scan, env: a(v, h, now, scan, env) is None
        case Not(operand=operand):
            a = _value(operand, slots, times)
            return lambda v, h, now, scan, env: not a(v, h, now, scan, env)
        case And(operands=operands):
            fns = [_value(o, slots, times) for o in operands]
            return lambda v, h, now, scan, env: _all(fns, v, h, now, scan, env)
        case Or(operands=operands):
            fns = [_value(o, slots, times) for o in operands]
            return lambda v, h, now, scan, env: _any(fns, v, h, now, scan, env)
        case Call(owner=owner, method=method, args=args):
            fns = [_value(a, slots, times) for a in args]
            # (looked up at each call, as the printed form does)
            return lambda v, h, now, scan, env: getattr(owner, method)(
                *[fn(v, h, now, scan, env) for fn in fns])
        case Apply(function=function, args=args):
            held = _value(function, slots, times)
            fns = [_value(a, slots, times) for a in args]
            return lambda v, h, now, scan, env: held(v, h, now, scan, env)(
                *[fn(v, h, now, scan, env) for fn in fns])
    raise TypeError(f"not a value of the scan program: {value!r}")


def _all(fns: list[ValueFn], v: Image, h: History, now: int, scan: int, env: Env) -> Any:
    """Python's ``and``: the first false operand's value, else the last one's."""
    result: Any = True
    for fn in fns:
        result = fn(v, h, now, scan, env)
        if not result:
            return result
    return result


def _any(fns: list[ValueFn], v: Image, h: History, now: int, scan: int, env: Env) -> Any:
    result: Any = False
    for fn in fns:
        result = fn(v, h, now, scan, env)
        if result:
            return result
    return result
