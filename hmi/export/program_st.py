"""The scan program (hmi.program.ir) printed as IEC 61131-3 statements of the PLC model.

The third printer of the one program (beside the Python the engine runs and the reference
evaluator): a stage's lowering becomes the body of its function block, rule by rule as the
engine runs it, so a TON, an observer, a GRAFCET's enabling or an equation is not written a
second time for the PLC.

What a printer of the IR needs to know of the PLC side, the caller gives (:class:`Places`):
where each image slot lives in the POU (a variable of its own, an input the program wires,
a global), how a project expression reads (hmi.export.views.convert), where each runtime
object's state cell lives (a variable of the POU, declared with the object's value at export
time as its initial value) and the ST version of each handler the program calls
(:class:`Handler`: a rare event's bookkeeping written as statements).

Types: Boolean values are BOOL; the scan's time and everything computed from it TIME (the
program's clock, ``Now``, a TIME that only ever grows); integer constants take the type of
what they are compared with or added to (a TIME constant must be whole milliseconds:
Durations says where one is not); a value that may be None (a timer's start, the last scan a
stage ran) is a TIME or DINT with a BOOL beside it saying "none" (no literal stands for "no
time"); a local that collects constant tuples (the fireable transitions) is one BOOL per
element it can hold. The scan's number, where a program compares it, is a DINT the block
counts itself (``Places.scan``); a handler whose value a program tests (``if
stage.lost_sight(...)``, ``armed and stage.refine(...)``: called only when ``armed``)
writes it to a BOOL local (``Handler.value``). A word of bits (the filter's active
constraints) is a DWORD or LWORD variable of the POU the program's local is bound to
(``Places.locals``); its constants take that type.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from hmi.errors import SourcePos
from hmi.export import model as m
from hmi.export.names import Scope
from hmi.export.views import Durations
from hmi.logic.expr import And, Compare, Const, Duration, Node, Not, Or, StepTime, Var
from hmi.program import ir

BOOL, TIME, INT, DINT, NTIME, NDINT, SET = ("BOOL", "TIME", "INT", "DINT", "NTIME", "NDINT",
                                            "SET")
INTEGERS = (INT, DINT)
WORDS = ("DWORD", "LWORD")  # words of bits (hmi.program.ir.Bits)
NULLABLE = {NTIME: TIME, NDINT: DINT}  # a value that may be None, and its type when not
_UNTYPED = "ANY_INT"  # an integer constant, typed by its use
_UNTYPED_BITS = "ANY_BIT"  # a constant word of bits, typed by its use
_NONE = "NONE"  # the constant None
_COMPARE = {"==": "=", "!=": "<>", "<": "<", "<=": "<=", ">": ">", ">=": ">="}


class NotPrintable(Exception):
    """A part of the scan program the ST printer has no form for (a handler without an ST
    version, a Python-only construct): a bug of the export, named."""


@dataclass(frozen=True)
class Place:
    """Where a value lives in the POU: its variable, its type (BOOL, INT, DINT, TIME, NTIME
    or NDINT) and, for NTIME and NDINT, the BOOL that says it holds None."""

    name: str
    type: str
    none: str | None = None

    @property
    def expr(self) -> m.Name:
        return m.Name(self.name)


@dataclass
class Handler:
    """The ST version of one handler method: ``print(printer, args) -> statements``, each
    argument printed (:meth:`StPrinter.value`, or the element names of a collected set).
    A handler whose value the program tests has ``value(printer, args, result)`` instead:
    the statements that write the value to the BOOL variable `result`."""

    print: Callable[[StPrinter, tuple[Any, ...]], list[m.Stmt]] | None = None
    value: Callable[[StPrinter, tuple[Any, ...], m.Name], list[m.Stmt]] | None = None


@dataclass
class Places:
    """The PLC side of a stage's lowering (see the module docstring)."""

    slot: Callable[[int], Place]
    read: Callable[[str, int], m.Expr]  # a project name at a depth, as this POU reads it
    step_time: Callable[[str], m.Expr]  # a step's activity time (TIME)
    now: m.Expr | None = None  # the scan's time (None: the program reads none)
    scan: m.Expr | None = None  # the scan's number (DINT), where the program compares it
    # locals of the program that are variables of the POU (the filter's words, its policy)
    locals: dict[str, Place] = field(default_factory=dict)
    # locals the PLC does not keep (a handler's decision only the engine reads): a handler's
    # value given to one is its ST version's statements, any other value nothing
    unkept: frozenset[str] = frozenset()
    cells: dict[tuple[int, Any], Place | None] = field(default_factory=dict)
    handlers: dict[tuple[int, str], Handler] = field(default_factory=dict)
    # runtime objects the program compares by identity (``is``), as INT codes
    codes: dict[int, int] = field(default_factory=dict)

    def cell(self, owner: Any, attr: Any, place: Place | None) -> None:
        """`owner`'s `attr` (an attribute name, or an index of a list handed over) lives at
        `place` (None: not kept in the PLC, an assignment to it is left out)."""
        self.cells[(id(owner), attr)] = place

    def handler(self, owner: Any, method: str, handler: Handler) -> None:
        self.handlers[(id(owner), method)] = handler

    def code(self, obj: Any, number: int) -> None:
        """`obj` (a phase, compared with ``is``) is the INT `number` in the PLC."""
        self.codes[id(obj)] = number


class StPrinter:
    """Prints statements of the scan program with `places`; the locals it needs are
    allocated in `scope` and listed in :attr:`locals` (their declarations)."""

    def __init__(self, places: Places, scope: Scope, durations: Durations, pos: SourcePos,
                 what: str):
        self.places = places
        self.scope = scope
        self.durations = durations
        self.pos = pos  # where a duration that is not whole milliseconds is reported
        self.what = what
        self.locals: list[m.Var] = []
        self._locals: dict[str, Place] = dict(places.locals)
        self._sets: dict[str, dict[int, str]] = {}

    # -- statements --------------------------------------------------------------------------
    def program(self, stmts: Iterable[ir.Stmt]) -> list[m.Stmt]:
        stmts = tuple(stmts)
        self._collect_sets(stmts)
        out: list[m.Stmt] = []
        for stmt in stmts:
            out += self.stmt(stmt)
        return out

    def block(self, stmts: tuple[ir.Stmt, ...]) -> tuple[m.Stmt, ...]:
        out: list[m.Stmt] = []
        for stmt in stmts:
            out += self.stmt(stmt)
        return tuple(out)

    def stmt(self, stmt: ir.Stmt) -> list[m.Stmt]:
        if isinstance(stmt, ir.Assign):
            return self._assign(stmt.target, stmt.value)
        if isinstance(stmt, ir.If):
            before: list[m.Stmt] = []
            test = stmt.test
            if isinstance(test, ir.Call):  # a handler's value: written, then tested
                local = self._result(test.method)
                before = self._call(test, self._locals[local].expr)
                stmt = ir.If(ir.Local(local), stmt.then, stmt.orelse)
            elif isinstance(test, ir.And) and isinstance(test.operands[-1], ir.Call):
                # `a and handler(...)`: the handler runs only when `a` holds
                call = test.operands[-1]
                local = self._result(call.method)
                result = self._locals[local].expr
                guard = self.boolean(ir.And(test.operands[:-1]) if len(test.operands) > 2
                                     else test.operands[0])
                before = [m.Assign(result, m.FALSE),
                          m.if_(guard, *self._call(call, result))]
                stmt = ir.If(ir.Local(local), stmt.then, stmt.orelse)
            branches: list[tuple[m.Expr, tuple[m.Stmt, ...]]] = []
            node: ir.If = stmt
            while True:
                branches.append((self.boolean(node.test), self.block(node.then)))
                orelse = node.orelse
                if len(orelse) == 1 and isinstance(orelse[0], ir.If):
                    node = orelse[0]
                    continue
                last = self.block(orelse)
                # (a last branch with nothing to do, e.g. a handler with no ST statements,
                # changes nothing: left out)
                while branches and not branches[-1][1] and not last:
                    branches.pop()
                return [*before, m.If(tuple(branches), last)] if branches else before
        if isinstance(stmt, ir.Do) and isinstance(stmt.call, ir.Call):
            return self._call(stmt.call)
        if isinstance(stmt, ir.Switch):
            selector, kind = self.value(stmt.value)
            if kind not in (*INTEGERS, _UNTYPED):
                raise NotPrintable(f"a switch on a {kind}")
            return [m.Case(selector, tuple(((int(key),), self.block(body))
                                           for key, body in stmt.cases),
                           self.block(stmt.default))]
        raise NotPrintable(f"{type(stmt).__name__} has no ST form in a stage's program")

    def _assign(self, target: ir.Target, value: ir.Value) -> list[m.Stmt]:
        if isinstance(target, ir.Local) and target.name in self.places.unkept:
            return self._call(value) if isinstance(value, ir.Call) else []
        if isinstance(target, ir.Local) and target.name in self._sets:
            return self._assign_set(target.name, value)
        if isinstance(target, ir.Local) and target.name not in self._locals:
            self._declare(target.name, self._type_of(value))
        place = self._place(target)
        if place is None:
            return []  # a cell the PLC does not keep
        if place.type in NULLABLE:
            assert place.none is not None
            if isinstance(value, ir.Const) and value.value is None:
                return [m.Assign(m.Name(place.none), m.TRUE)]
            source = self._nullable(value)
            if source is not None:
                assert source.none is not None
                return [m.Assign(place.expr, source.expr),
                        m.Assign(m.Name(place.none), m.Name(source.none))]
            expr, _ = self._typed(value, NULLABLE[place.type])
            return [m.Assign(place.expr, expr), m.Assign(m.Name(place.none), m.FALSE)]
        expr, _ = self._typed(value, place.type)
        return [m.Assign(place.expr, expr)]

    def _assign_set(self, name: str, value: ir.Value) -> list[m.Stmt]:
        elements = self._sets[name]
        if isinstance(value, ir.Const) and value.value == ():
            return [m.Assign(m.Name(ident), m.FALSE) for ident in elements.values()]
        if (isinstance(value, ir.Add) and value.left == ir.Local(name)
                and isinstance(value.right, ir.Const)
                and isinstance(value.right.value, tuple)):
            return [m.Assign(m.Name(elements[k]), m.TRUE) for k in value.right.value]
        raise NotPrintable(f"the collected local {name!r} is given {value!r}")

    def _result(self, method: str) -> str:
        """The BOOL local for a handler's value (one per method: it is written right before
        it is tested)."""
        if method not in self._locals:
            self._declare(method, BOOL)
        elif self._locals[method].type != BOOL:
            raise NotPrintable(f"the local {method!r} is not a BOOL")
        return method

    def _call(self, call: ir.Call, result: m.Name | None = None) -> list[m.Stmt]:
        handler = self.places.handlers.get((id(call.owner), call.method))
        what = f"{type(call.owner).__name__}.{call.method}"
        if handler is None:
            raise NotPrintable(f"{what} has no ST version")
        printer = handler.print if result is None else None
        if (handler.value if result is not None else printer) is None:
            raise NotPrintable(f"{what} has no ST version "
                               + ("giving its value" if result is not None else "as a call"))
        args: list[Any] = []
        for arg in call.args:
            if isinstance(arg, ir.Local) and arg.name in self._sets:
                args.append(dict(self._sets[arg.name]))
            elif isinstance(arg, ir.TheImage | ir.TheHistory | ir.ScanNumber):
                # (the handler's ST version reaches the places itself; a PLC numbers no
                # scans)
                args.append(None)
            else:
                args.append(self.value(arg)[0])
        if result is not None:
            assert handler.value is not None
            return handler.value(self, tuple(args), result)
        assert printer is not None
        return printer(self, tuple(args))

    # -- places ------------------------------------------------------------------------------
    def _declare(self, name: str, kind: str) -> Place:
        if kind == _UNTYPED:
            kind = INT
        if kind not in (BOOL, INT, DINT, TIME, NTIME, NDINT):
            raise NotPrintable(f"the local {name!r} would be a {kind}")
        ident = self.scope.take(f"L_{name}")
        none = self.scope.take(f"L_{name}_none") if kind in NULLABLE else None
        plc_type = {BOOL: m.BOOL, INT: m.INT, DINT: m.DINT, TIME: m.TIME, NTIME: m.TIME,
                    NDINT: m.DINT}[kind]
        self.locals.append(m.Var(ident, plc_type, comment=f"{self.what}: {name}"))
        if none is not None:
            self.locals.append(m.Var(none, m.BOOL, comment=f"{name} holds no "
                                     + ("time" if kind == NTIME else "number")))
        place = self._locals[name] = Place(ident, kind, none)
        return place

    def _place(self, target: ir.Value) -> Place | None:
        if isinstance(target, ir.Local):
            found = self._locals.get(target.name)
            if found is None:
                raise NotPrintable(f"the local {target.name!r} is read before it is set")
            return found
        if isinstance(target, ir.Slot):
            return self.places.slot(target.index)
        if isinstance(target, ir.Cell):
            return self._cell(target.owner, target.attr)
        if isinstance(target, ir.Item) and isinstance(target.base, ir.Ref):
            return self._cell(target.base.obj, target.index)
        raise NotPrintable(f"{target!r} is not a place of the PLC program")

    def _cell(self, owner: Any, attr: Any) -> Place | None:
        key = (id(owner), attr)
        if key not in self.places.cells:
            raise NotPrintable(f"{type(owner).__name__}.{attr} has no place in the PLC")
        return self.places.cells[key]

    def _nullable(self, value: ir.Value) -> Place | None:
        if isinstance(value, ir.Local | ir.Slot | ir.Cell | ir.Item):
            place = self._place(value)
            if place is not None and place.type in NULLABLE:
                return place
        return None

    # -- values ------------------------------------------------------------------------------
    def boolean(self, value: ir.Value) -> m.Expr:
        if isinstance(value, ir.Local) and value.name in self._sets:
            return m.or_(*(m.Name(i) for i in self._sets[value.name].values()))
        expr, _ = self._typed(value, BOOL)
        return expr

    def _typed(self, value: ir.Value, kind: str) -> tuple[m.Expr, str]:
        """`value` where a `kind` is expected (an integer constant or a constant word of
        bits takes it)."""
        if isinstance(value, ir.Const) and isinstance(value.value, int) \
                and not isinstance(value.value, bool):
            return self._constant(value.value, kind), kind
        if isinstance(value, ir.Bits | ir.Bit):
            if kind not in WORDS:
                raise NotPrintable(f"a word of bits where a {kind} is expected")
            word = value.value if isinstance(value, ir.Bits) else 1 << value.index
            if word >> (32 if kind == "DWORD" else 64):
                raise NotPrintable(f"the word {word:#x} does not fit a {kind}")
            return m.BitsLit(word, kind), kind
        expr, found = self.value(value)
        found = NULLABLE.get(found, found)
        if kind != found and not (kind in INTEGERS and found == _UNTYPED):
            raise NotPrintable(f"{value!r} is a {found} where a {kind} is expected")
        return expr, found

    def _constant(self, number: int, kind: str) -> m.Expr:
        if kind == TIME:
            return self.durations.time(int(number), self.pos, self.what)
        if kind in (*INTEGERS, _UNTYPED):
            return m.IntLit(int(number))
        if kind in WORDS:
            return m.BitsLit(int(number), kind)
        raise NotPrintable(f"the constant {number} where a {kind} is expected")

    def _type_of(self, value: ir.Value) -> str:
        if isinstance(value, ir.Const) and value.value is None:
            return NTIME
        nullable = self._nullable(value)
        if nullable is not None:
            return nullable.type
        return self.value(value)[1]

    def value(self, value: ir.Value) -> tuple[m.Expr, str]:
        """`value` as a PLC expression and its type."""
        match value:
            case ir.Test(node=node):
                return self.test(node), BOOL
            case ir.Now():
                if self.places.now is None:
                    raise NotPrintable("the scan's time is read but not wired here")
                return self.places.now, TIME
            case ir.ScanNumber():
                if self.places.scan is None:
                    raise NotPrintable("the scan's number is read but not counted here")
                return self.places.scan, DINT
            case ir.Const(value=constant):
                if isinstance(constant, bool):
                    return m.BoolLit(constant), BOOL
                if isinstance(constant, int):
                    return m.IntLit(constant), _UNTYPED
                raise NotPrintable(f"the constant {constant!r} has no ST form here")
            case ir.Ref(obj=obj) if id(obj) in self.places.codes:
                return m.IntLit(self.places.codes[id(obj)]), INT
            case ir.Item(base=ir.Local(name=name), index=index) if (
                    name in self._locals and self._locals[name].type in WORDS):
                # bit `index` of a word (the filter's candidate vector)
                word = self._locals[name]
                return m.Binary("<>", m.Binary("AND", word.expr, m.BitsLit(1 << index,
                                                                            word.type)),
                                m.BitsLit(0, word.type)), BOOL
            case ir.Local() | ir.Slot() | ir.Cell() | ir.Item():
                place = self._place(value)
                if place is None:
                    raise NotPrintable(f"{value!r} is read but not kept in the PLC")
                return place.expr, place.type
            case ir.Bits() | ir.Bit():
                raise NotPrintable("a word of bits where no word is expected")
            case ir.BitOr(left=left, right=right):
                kind = self._word_type(left, right)
                a, _ = self._typed(left, kind)
                b, _ = self._typed(right, kind)
                return m.Binary("OR", a, b), kind
            case ir.Add(left=left, right=right) | ir.Sub(left=left, right=right):
                kind = self._arith_type(left, right)
                a, _ = self._typed(left, kind)
                b, _ = self._typed(right, kind)
                return m.Binary("+" if isinstance(value, ir.Add) else "-", a, b), kind
            case ir.Compare(op="is", left=left, right=ir.Ref(obj=obj)):
                code = self.places.codes.get(id(obj))
                if code is None:
                    raise NotPrintable(f"{obj!r} has no code in the PLC")
                a, _ = self._typed(left, INT)
                return m.Binary("=", a, m.IntLit(code)), BOOL
            case ir.Compare(op=op, left=left, right=right):
                if op not in _COMPARE:
                    raise NotPrintable(f"the comparison {op!r} has no ST form")
                kind = self._arith_type(left, right)
                a, _ = self._typed(left, kind)
                b, _ = self._typed(right, kind)
                return m.Binary(_COMPARE[op], a, b), BOOL
            case ir.IsNone(operand=operand):
                place = self._nullable(operand)
                if place is None or place.none is None:
                    raise NotPrintable(f"{operand!r} cannot hold None in the PLC")
                return m.Name(place.none), BOOL
            case ir.Not(operand=operand):
                return m.not_(self.boolean(operand)), BOOL
            case ir.And(operands=operands):
                return m.and_(*(self.boolean(o) for o in operands)), BOOL
            case ir.Or(operands=operands):
                return m.or_(*(self.boolean(o) for o in operands)), BOOL
        raise NotPrintable(f"{type(value).__name__} has no ST form as a value")

    def _arith_type(self, left: ir.Value, right: ir.Value) -> str:
        # (a value that may be None is read where the program knows it is not)
        kinds = {NULLABLE.get(k, k) for k in (self._peek(left), self._peek(right))}
        kinds.discard(_UNTYPED)
        if not kinds:
            return INT
        if len(kinds) > 1:
            raise NotPrintable(f"{left!r} and {right!r} are of types {sorted(kinds)}")
        (kind,) = kinds
        return kind

    def _word_type(self, left: ir.Value, right: ir.Value) -> str:
        kinds = {self._peek(left), self._peek(right)} - {_UNTYPED_BITS}
        if len(kinds) != 1 or not kinds <= set(WORDS):
            raise NotPrintable(f"{left!r} and {right!r} are not words of one type")
        (kind,) = kinds
        return kind

    def _peek(self, value: ir.Value) -> str:
        if isinstance(value, ir.Bits | ir.Bit):
            return _UNTYPED_BITS
        if isinstance(value, ir.Const) and isinstance(value.value, int) \
                and not isinstance(value.value, bool):
            return _UNTYPED
        return self.value(value)[1]

    def test(self, node: Node) -> m.Expr:
        """A project expression, as this POU reads its names."""
        if isinstance(node, Const):
            return m.BoolLit(node.value)
        if isinstance(node, Var):
            return self.places.read(node.name, node.depth)
        if isinstance(node, Not):
            return m.not_(self.test(node.operand))
        if isinstance(node, And):
            return m.and_(*(self.test(op) for op in node.operands))
        if isinstance(node, Or):
            return m.or_(*(self.test(op) for op in node.operands))
        if isinstance(node, Compare):
            return m.Binary(_COMPARE[node.op], self._time(node.left), self._time(node.right))
        raise NotPrintable(f"not a Boolean expression: {node!r}")

    def _time(self, node: Node) -> m.Expr:
        if isinstance(node, Duration):
            return self.durations.time(int(node.us), self.pos, self.what)
        if isinstance(node, StepTime):
            return self.places.step_time(node.step)
        raise NotPrintable(f"not a time: {node!r}")

    # -- collected sets ----------------------------------------------------------------------
    def _collect_sets(self, stmts: tuple[ir.Stmt, ...]) -> None:
        """The locals grown by ``local = local + (k,)``: one BOOL per element k."""
        found: dict[str, set[int]] = {}
        for assign in _assignments(stmts):
            value = assign.value
            if (isinstance(assign.target, ir.Local) and isinstance(value, ir.Add)
                    and value.left == assign.target and isinstance(value.right, ir.Const)
                    and isinstance(value.right.value, tuple)):
                found.setdefault(assign.target.name, set()).update(value.right.value)
        for name, elements in found.items():
            idents = {}
            for k in sorted(elements):
                ident = idents[k] = self.scope.take(f"L_{name}_{k}")
                self.locals.append(m.Var(ident, m.BOOL, comment=f"{self.what}: {k} in {name}"))
            self._sets[name] = idents


def _assignments(stmts: tuple[ir.Stmt, ...]) -> Iterable[ir.Assign]:
    for stmt in stmts:
        if isinstance(stmt, ir.Assign):
            yield stmt
        elif isinstance(stmt, ir.If):
            yield from _assignments(stmt.then)
            yield from _assignments(stmt.orelse)
        elif isinstance(stmt, ir.Switch):
            for _, body in stmt.cases:
                yield from _assignments(body)
            yield from _assignments(stmt.default)
