"""Python source for a project's scan, generated from its parsed expressions.

Why generate code: a scan that calls one closure per node of every expression (hmi.logic.expr's
``compile_bool``) spends most of its time in calls. Here each expression becomes one Python
expression over the image (``v[3] and not h[0][5]``), and a stage's whole work one function,
built once when the engine is built.

Why this is safe although project files are data and never evaluated: the source is written
only from the *parsed and validated* trees (hmi.logic.expr), and only from slot indices,
integer constants (durations, presets, window bounds) and a fixed vocabulary of operators and
local names. No text of a project file (a name, a description, a comment) is ever part of
it: objects a function needs (a timer, a diagnoser, a name used as a key) are handed to it as
default arguments ``k0``, ``k1``... And before anything is compiled, :func:`build` walks the
source's syntax tree and refuses any node, name or constant outside that vocabulary, so a bug
in a generator cannot turn into arbitrary code either.
"""

from __future__ import annotations

import ast
import dataclasses
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import CodeType
from typing import Any

from hmi.logic.expr import And, Compare, Const, Duration, Node, Not, Or, StepTime, Var
from hmi.program import ir

_COMPARE = {"<": "<", "<=": "<=", ">": ">", ">=": ">=", "==": "==", "!=": "!="}


def expr_source(node: Node, slots: Mapping[str, int], times: Mapping[str, int]) -> str:
    """One Boolean expression as Python source over ``v`` (the image) and ``h`` (the history:
    ``h[0]`` is the image one scan ago). Evaluates to the same value as
    ``compile_bool(node, slots, times)`` (bools in, bools out), with the same short-circuits."""
    if isinstance(node, Const):
        return "True" if node.value else "False"
    if isinstance(node, Var):
        slot = int(slots[node.name])
        if node.depth == 0:
            return f"v[{slot}]"
        return f"h[{int(node.depth) - 1}][{slot}]"
    if isinstance(node, Not):
        return f"(not {expr_source(node.operand, slots, times)})"
    if isinstance(node, (And, Or)):
        word = " and " if isinstance(node, And) else " or "
        return "(" + word.join(expr_source(op, slots, times) for op in node.operands) + ")"
    if isinstance(node, Compare):
        op = _COMPARE[node.op]
        return (f"({_num_source(node.left, times)} {op} "
                f"{_num_source(node.right, times)})")
    raise TypeError(f"not a Boolean node: {node!r}")


def _num_source(node: Node, times: Mapping[str, int]) -> str:
    if isinstance(node, Duration):
        return str(int(node.us))
    if isinstance(node, StepTime):
        return f"v[{int(times[node.step])}]"
    raise TypeError(f"not a numeric node: {node!r}")


class Source:
    """Lines of generated code and the objects they use, handed over as default arguments."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.objects: list[Any] = []
        self._known: dict[int, str] = {}

    def ref(self, obj: Any) -> str:
        """The local name (``k<n>``) under which the generated code sees `obj`."""
        name = self._known.get(id(obj))
        if name is None:
            name = self._known[id(obj)] = f"k{len(self.objects)}"
            self.objects.append(obj)
        return name

    def line(self, indent: int, text: str) -> None:
        self.lines.append("    " * indent + text)

    def defaults(self) -> str:
        """The parameters binding every object (fast local look-ups). Positional ones with
        defaults, not keyword-only: a call fills positional defaults from a tuple, but looks
        each missing keyword-only one up by name in a dict (the palletizer's core and
        monitors, 31 objects, paid some 4,000 instructions a scan for it)."""
        return "".join(f", k{n}=k{n}" for n in range(len(self.objects)))


def build_function(function: ir.Function, slots: Mapping[str, int],
                   times: Mapping[str, int], label: str) -> Callable[..., Any]:
    """`function` printed as Python and built (:func:`build`)."""
    src = Source()
    if function.body:
        print_program(src, _cell_tests(function.body, function.result), 1, slots, times)
    if function.result is not None:
        src.line(1, f"return {_value_source(src, function.result, slots, times)}")
    return build(src, function.name, ", ".join(function.params),
                 f"<plchmi compiled {function.name}: {label}>")


def _cell_tests(body: tuple[ir.Stmt, ...], result: ir.Value | None) -> tuple[ir.Stmt, ...]:
    """`body` (a function's, returning `result`) with each ``p = cell`` followed by ``if p
    is x: A else: B``, where neither x nor A reads p and nothing after reads it before
    setting it again, printed as ``if cell is x: A else: p = cell; B``: a monitor's test of
    its phase (hmi.program.monitors), whose idle branch most scans of most monitors take,
    without the local (two bytecodes a monitor). The cell is read where the local was
    used, nothing running in between: the same value."""
    out: list[ir.Stmt] = []
    at = 0
    while at < len(body):
        stmt, test = body[at], body[at + 1] if at + 1 < len(body) else None
        if (isinstance(stmt, ir.Assign) and isinstance(stmt.target, ir.Local)
                and isinstance(stmt.value, ir.Cell) and isinstance(test, ir.If)
                and isinstance(test.test, ir.Compare) and test.test.op == "is"
                and test.test.left == stmt.target
                and not _mentions((test.test.right, test.then), stmt.target)
                and not _read_later(body[at + 2:], result, stmt.target)):
            out.append(ir.If(ir.Compare("is", stmt.value, test.test.right), test.then,
                             (stmt, *test.orelse)))
            at += 2
            continue
        out.append(stmt)
        at += 1
    return tuple(out)


def _read_later(rest: tuple[ir.Stmt, ...], result: ir.Value | None, local: ir.Local) -> bool:
    """Whether `local` may be read by `rest` or `result` before `rest` sets it again."""
    for stmt in rest:
        if (isinstance(stmt, ir.Assign) and stmt.target == local
                and not _mentions(stmt.value, local)):
            return False
        if _mentions(stmt, local):
            return True
    return result is not None and _mentions(result, local)


def print_program(src: Source, program: tuple[ir.Stmt, ...], indent: int,
                  slots: Mapping[str, int], times: Mapping[str, int],
                  words: bool = True) -> None:
    """`program`'s statements as Python lines of `src` (the compiled scan's printer of the
    scan program, hmi.program.ir): a cell is an attribute of the object handed over, a
    handler's call a method call, an ``if`` whose else branch is one ``if`` an ``elif``, a
    switch a tree of comparisons (a chain up to three cases), a local or-ed with a word
    ``|=``, a run of them under one test (_word_run; not again inside it: `words`)."""
    if not program:
        src.line(indent, "pass")
        return
    at = 0
    while at < len(program):
        stmt = program[at]
        run = _word_run(program, at) if words and indent < MAX_GROUP_INDENT else ()
        if len(run) >= 3:  # (a word's bits: most scans set none)
            print_program(src, _grouped(run, indent), indent, slots, times, words=False)
            at += len(run)
            continue
        at += 1
        if isinstance(stmt, ir.If):
            src.line(indent, f"if {_value_source(src, stmt.test, slots, times)}:")
            _print_branches(src, stmt, indent, slots, times)
        elif isinstance(stmt, ir.Switch):
            if not isinstance(stmt.value, ir.Local):
                raise TypeError("a switch selects on a local")
            cases = sorted(stmt.cases)
            if len({key for key, _ in cases}) != len(cases):
                raise ValueError("a switch with a case twice")
            _print_switch(src, stmt.value.name, cases, stmt.default, indent, slots, times)
        elif isinstance(stmt, ir.Do):
            src.line(indent, _value_source(src, stmt.call, slots, times))
        elif isinstance(stmt, ir.Return):
            src.line(indent, f"return {_value_source(src, stmt.value, slots, times)}")
        elif isinstance(stmt, ir.Try):
            src.line(indent, "try:")
            print_program(src, stmt.body, indent + 1, slots, times)
            for kind, name, handler in stmt.handlers:
                src.line(indent, f"except {src.ref(kind)} as {name}:")
                print_program(src, handler, indent + 1, slots, times)
        elif (isinstance(stmt.value, ir.BitOr) and isinstance(stmt.target, ir.Local)
              and stmt.value.left == stmt.target):
            src.line(indent, f"{stmt.target.name} |= "
                             f"{_value_source(src, stmt.value.right, slots, times)}")
        else:
            src.line(indent, f"{_value_source(src, stmt.target, slots, times)} = "
                             f"{_value_source(src, stmt.value, slots, times)}")


def _word_run(program: tuple[ir.Stmt, ...], at: int) -> tuple[ir.If, ...]:
    """The ``if`` statements from `at` on that each only or a bit into one local word (a
    word of the constraints: active, violated), their tests pure reads that do not read it:
    in any order they set the same bits (_grouped)."""
    run: list[ir.If] = []
    word: ir.Local | None = None
    for stmt in program[at:]:
        if not (isinstance(stmt, ir.If) and not stmt.orelse and len(stmt.then) == 1):
            break
        (body,) = stmt.then
        if not (isinstance(body, ir.Assign) and isinstance(body.target, ir.Local)
                and isinstance(body.value, ir.BitOr) and body.value.left == body.target
                and isinstance(body.value.right, ir.Bit)
                and (word is None or body.target == word)):
            break
        word = body.target
        if not _pure(stmt.test) or _mentions(stmt.test, word):
            break
        run.append(stmt)
    return tuple(run)


# The indentation down to which a word's ifs are grouped: Python compiles at most 100 nested
# blocks, and a project's constraints may share many literals (tests/test_costs.py's project
# at the limits nested past it); the first levels are where the scans' savings are.
MAX_GROUP_INDENT = 16


def _grouped(run: tuple[ir.If, ...], depth: int) -> tuple[ir.Stmt, ...]:
    """A word's ifs (_word_run) gathered under the first operand of their tests, recursively
    while `depth` (the indentation) is under MAX_GROUP_INDENT: ``if a and b: w |= 1`` and
    ``if a and c: w |= 2`` become ``if a:`` over ``if b: w |= 1`` and ``if c: w |= 2``;
    where `a` is false (an output off, a step inactive) one test passes the group over.
    Groups where their operand first appears."""
    if depth >= MAX_GROUP_INDENT:
        return run
    groups: dict[ir.Value, list[tuple[tuple[ir.Value, ...], tuple[ir.Stmt, ...]]]] = {}
    for stmt in run:
        factors = stmt.test.operands if isinstance(stmt.test, ir.And) else (stmt.test,)
        groups.setdefault(factors[0], []).append((factors[1:], stmt.then))
    out: list[ir.Stmt] = []
    for head, members in groups.items():
        if len(members) == 1:
            rest, then = members[0]
            out.append(ir.If(ir.all_of(head, *rest), then))
            continue
        inner: list[ir.Stmt] = []
        for rest, then in members:
            inner.extend(then if not rest else (ir.If(ir.all_of(*rest), then),))
        body = tuple(inner)
        ifs = tuple(stmt for stmt in body if isinstance(stmt, ir.If))
        out.append(ir.If(head, (*(stmt for stmt in body if not isinstance(stmt, ir.If)),
                                *(_grouped(ifs, depth + 1) if len(ifs) > 1 else ifs))))
    return tuple(out)


def _mentions(value: object, local: ir.Local) -> bool:
    """Whether the scan program's `value` reads `local`."""
    if value == local:
        return True
    if isinstance(value, tuple):
        return any(_mentions(item, local) for item in value)
    if dataclasses.is_dataclass(value) and type(value).__module__ == ir.__name__:
        return any(_mentions(getattr(value, field.name), local)
                   for field in dataclasses.fields(value))
    return False


def _print_branches(src: Source, stmt: ir.If, indent: int, slots: Mapping[str, int],
                    times: Mapping[str, int]) -> None:
    print_program(src, stmt.then, indent + 1, slots, times)
    orelse = stmt.orelse
    if len(orelse) == 1 and isinstance(orelse[0], ir.If):
        src.line(indent, f"elif {_value_source(src, orelse[0].test, slots, times)}:")
        _print_branches(src, orelse[0], indent, slots, times)
    elif orelse:
        src.line(indent, "else:")
        print_program(src, orelse, indent + 1, slots, times)


def _print_switch(src: Source, name: str, cases: list[tuple[int, tuple[ir.Stmt, ...]]],
                  default: tuple[ir.Stmt, ...], indent: int, slots: Mapping[str, int],
                  times: Mapping[str, int]) -> None:
    """A chain of equality tests for up to three cases, else a comparison with the middle
    key splitting the cases in two (some log2(n) comparisons instead of n/2)."""
    if len(cases) <= 3:
        for k, (key, body) in enumerate(cases):
            src.line(indent, f"{'if' if k == 0 else 'elif'} {name} == {int(key)}:")
            print_program(src, body, indent + 1, slots, times)
        if default and cases:
            src.line(indent, "else:")
            print_program(src, default, indent + 1, slots, times)
        elif default:
            print_program(src, default, indent, slots, times)
        return
    middle = len(cases) // 2
    src.line(indent, f"if {name} < {int(cases[middle][0])}:")
    _print_switch(src, name, cases[:middle], default, indent + 1, slots, times)
    src.line(indent, "else:")
    _print_switch(src, name, cases[middle:], default, indent + 1, slots, times)


def _value_source(src: Source, value: ir.Value, slots: Mapping[str, int],
                  times: Mapping[str, int]) -> str:
    match value:
        case ir.Test(node=node):
            return expr_source(node, slots, times)
        case ir.Now():
            return "now"
        case ir.ScanNumber():
            return "scan"
        case ir.TheImage():
            return "v"
        case ir.TheHistory():
            return "h"
        case ir.Const(value=constant):
            return _constant_source(constant)
        case ir.Local(name=name):
            return name
        case ir.Slot(index=index):
            return f"v[{int(index)}]"
        case ir.Cell(owner=owner, attr=attr):
            return f"{src.ref(owner)}.{attr}"
        case ir.Ref(obj=obj):
            return src.ref(obj)
        case ir.Item(base=base, index=index):
            return f"{_operand_source(src, base, slots, times)}[{int(index)}]"
        case ir.Field(base=base, name=name):
            return f"{_operand_source(src, base, slots, times)}.{name}"
        case ir.Tuple(items=items):
            return "(" + "".join(f"{_value_source(src, i, slots, times)}, " for i in items) + ")"
        case ir.Bits(value=bits):
            # (handed over: thousands of constraints make a word of thousands of digits)
            return src.ref(bits)
        case ir.Bit(index=index):
            # (a shift, folded by the compiler: not the value, thousands of digits long)
            return f"1 << {int(index)}"
        case ir.BitOr(left=left, right=right):
            return (f"{_operand_source(src, left, slots, times)} | "
                    f"{_operand_source(src, right, slots, times)}")
        case ir.Add(left=left, right=right) | ir.Sub(left=left, right=right):
            sign = "+" if isinstance(value, ir.Add) else "-"
            return (f"{_operand_source(src, left, slots, times)} {sign} "
                    f"{_operand_source(src, right, slots, times)}")
        case ir.Compare(op=op, left=left, right=right):
            if op not in ir.COMPARISONS:
                raise ValueError(f"not a comparison of the scan program: {op!r}")
            left, right = _folded(left, right)
            return (f"{_operand_source(src, left, slots, times)} {op} "
                    f"{_operand_source(src, right, slots, times)}")
        case ir.IsNone(operand=operand):
            return f"{_operand_source(src, operand, slots, times)} is None"
        case ir.Not(operand=operand):
            return f"(not {_value_source(src, operand, slots, times)})"
        case ir.And(operands=operands) | ir.Or(operands=operands):
            word = " and " if isinstance(value, ir.And) else " or "
            return "(" + word.join(_value_source(src, o, slots, times) for o in operands) + ")"
        case ir.Apply(function=function, args=args):
            return (f"{_operand_source(src, function, slots, times)}("
                    + ", ".join(_value_source(src, a, slots, times) for a in args) + ")")
        case ir.Call(owner=owner, method="__call__", args=args):
            return (f"{src.ref(owner)}("
                    + ", ".join(_value_source(src, a, slots, times) for a in args) + ")")
        case ir.Call(owner=owner, method=method, args=args):
            return (f"{src.ref(owner)}.{method}("
                    + ", ".join(_value_source(src, a, slots, times) for a in args) + ")")
    raise TypeError(f"not a value of the scan program: {value!r}")


def _folded(left: ir.Value, right: ir.Value) -> tuple[ir.Value, ir.Value]:
    """A comparison's sides with ``a + (c1 - b)`` against a constant c2 (a monitor's
    cannot-finish rule: x + (alpha - y) >= gamma) as ``a - b`` against c2 - c1 when that is
    not negative: the same truth on Python's integers, one subtraction and one new integer
    (an allocation) fewer."""
    if (isinstance(left, ir.Add) and isinstance(left.right, ir.Sub)
            and isinstance(left.right.left, ir.Const) and isinstance(right, ir.Const)
            and _integer(left.right.left.value) and _integer(right.value)):
        c1, c2 = left.right.left.value, right.value
        assert isinstance(c1, int) and isinstance(c2, int)
        if c2 >= c1:  # (printed code holds no negative constant: its vocabulary)
            return ir.Sub(left.left, left.right.right), ir.Const(c2 - c1)
    return left, right


def _integer(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _pure(value: ir.Value) -> bool:
    """Whether reading `value` only reads (no call): its parts may be read in another order,
    or once for several places, without changing what anything sees."""
    match value:
        case ir.Test() | ir.Now() | ir.ScanNumber() | ir.Const() | ir.Local() | ir.Slot() \
                | ir.Ref() | ir.Bit():
            return True
        case ir.Item(base=base) | ir.Field(base=base):
            return _pure(base)
        case ir.Not(operand=operand) | ir.IsNone(operand=operand):
            return _pure(operand)
        case ir.And(operands=operands) | ir.Or(operands=operands):
            return all(map(_pure, operands))
        case ir.Compare(left=left, right=right) | ir.Add(left=left, right=right) \
                | ir.Sub(left=left, right=right):
            return _pure(left) and _pure(right)
    return False


def _constant_source(constant: object) -> str:
    if constant is None or isinstance(constant, bool):
        return repr(constant)
    if isinstance(constant, int):
        return repr(int(constant))
    if isinstance(constant, tuple):
        return "(" + "".join(f"{int(k)}, " for k in constant) + ")"
    raise TypeError(f"not a constant of the scan program: {constant!r}")


def _operand_source(src: Source, value: ir.Value, slots: Mapping[str, int],
                    times: Mapping[str, int]) -> str:
    text = _value_source(src, value, slots, times)
    return f"({text})" if isinstance(value, ir.Add | ir.Sub | ir.Compare | ir.IsNone
                                     | ir.Bit | ir.BitOr) else text


# What generated code may contain: the statements and expressions of the templates below.
_NODES = (ast.Module, ast.FunctionDef, ast.arguments, ast.arg, ast.Return, ast.Assign,
          ast.AugAssign, ast.If, ast.Expr, ast.Name, ast.Load, ast.Store,
          ast.Subscript, ast.Attribute, ast.Constant, ast.BoolOp, ast.And, ast.Or, ast.UnaryOp,
          ast.Not, ast.Compare, ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.Eq, ast.NotEq, ast.Is,
          ast.IsNot, ast.Call, ast.Tuple, ast.BinOp, ast.Sub, ast.Add, ast.Pass, ast.BitOr,
          ast.LShift, ast.Try, ast.ExceptHandler)
_ALLOWED = frozenset(_NODES)


@dataclass(frozen=True)
class Vocabulary:
    """The names one stage's printed statements use: the attributes and methods of its
    objects (a timer's ``since``, a diagnoser's ``take``) and its locals. Declared by the
    stage's class beside the handlers they name (``PRINTED``: code, never a project's text),
    and allowed when the compiled scan prints that stage (:func:`allow`)."""

    attributes: frozenset[str] = frozenset()
    locals: frozenset[str] = frozenset()

    def union(self, *others: Vocabulary) -> Vocabulary:
        return Vocabulary(self.attributes.union(*(o.attributes for o in others)),
                          self.locals.union(*(o.locals for o in others)))


# Every function's parameters (the image, the history, the scan's time and number, a
# candidate vector) and the past images bound once (_bind_past)
PARAMETERS = Vocabulary(locals=frozenset({"v", "h", "now", "scan", "f", "h0", "h1", "h2",
                                          "h3"}))
# Local names: the parameters and the names of every stage allowed so far (allow), what
# generated code may name besides the objects handed over.
LOCALS: set[str] = set(PARAMETERS.locals)
_HANDED = re.compile(r"k[0-9]+\Z")
# Attributes the printed code reads, sets or calls on the objects it is given: the stages'
# (allow), none of its own.
ATTRIBUTES: set[str] = set()
_NAME = re.compile(r"[a-z_][a-z0-9_]*\Z")


def allow(vocabulary: Vocabulary) -> None:
    """Let printed code use `vocabulary`'s names (hmi.engine.compiled, for each stage it
    prints and for its own frame). The vocabulary only grows, by names declared in code;
    a name the checker would let reach Python's machinery (a dunder, a builtin: the code
    runs without builtins) or the handed-over objects' pattern is refused."""
    for name in (*vocabulary.attributes, *vocabulary.locals):
        if not _NAME.match(name) or name.startswith("__") or _HANDED.match(name):
            raise ValueError(f"not a name printed code may use: {name!r}")
    ATTRIBUTES.update(vocabulary.attributes)
    LOCALS.update(vocabulary.locals)


def _check(tree: ast.AST) -> None:
    """Refuse anything outside the templates' vocabulary (defence in depth, see module doc).

    A walk of its own rather than ``ast.walk``: a project with thousands of constraints
    generates functions of hundreds of thousands of nodes, and ``ast.walk`` (a generator per
    node, every field read through ``iter_fields``) took twice as long. The node's exact
    type must be in the vocabulary, so every list field walked holds nodes (or ``None``: a
    keyword-only parameter without a default)."""
    stack: list[Any] = [tree]
    pop, push = stack.pop, stack.append
    while stack:
        node = pop()
        kind = type(node)
        if kind not in _ALLOWED:
            raise ValueError(f"generated code holds a {kind.__name__}")
        if kind is ast.Name and not (node.id in LOCALS or _HANDED.match(node.id)):
            raise ValueError(f"generated code names {node.id!r}")
        if kind is ast.arg and not (node.arg in LOCALS or _HANDED.match(node.arg)):
            raise ValueError(f"generated code has the parameter {node.arg!r}")
        if kind is ast.ExceptHandler and node.name not in LOCALS:
            raise ValueError(f"generated code binds {node.name!r}")
        if kind is ast.Attribute and node.attr not in ATTRIBUTES:
            raise ValueError(f"generated code reads .{node.attr}")
        if kind is ast.Constant and not (
                node.value is None or isinstance(node.value, (bool, int))):
            raise ValueError(f"generated code holds the constant {node.value!r}")
        for field in kind._fields:
            value = getattr(node, field, None)
            if isinstance(value, ast.AST):
                push(value)
            elif isinstance(value, list):
                for item in value:
                    if isinstance(item, ast.AST):
                        push(item)
                    elif item is not None:
                        raise ValueError(f"generated code holds {item!r} in a {kind.__name__}")


# Compiled code by its text: every engine of a project generates the same texts (only the
# objects handed over differ), and a campaign builds one engine per run.
_CODE: dict[tuple[str, str], CodeType] = {}
CODE_CACHE = 2048


# The code objects of _CODE compiled, or checked (check_code), in this process, by key: an
# entry of the table that is not the very object here (kept_codes put it there) is checked.
_CHECKED: dict[tuple[str, str], CodeType] = {}


def check_code(code: CodeType, name: str) -> str | None:
    """Why `code` is not what :func:`build` compiles for function `name` (None: it is): a
    module that only defines `name` with the objects handed over as defaults, and a function
    whose names are the templates' locals and attributes, whose constants are None, Booleans,
    integers and tuples of them, with no nested code nor closure. The same vocabulary as
    :func:`_check`'s, read from the code object: a cached code object is what would run,
    whatever text it was filed under (its name checked here, its builtins empty at exec)."""
    if set(code.co_names) - {name} - {n for n in code.co_names if _HANDED.match(n)}:
        return f"the module names {sorted(code.co_names)}"
    functions = [c for c in code.co_consts if isinstance(c, CodeType)]
    if len(functions) != 1 or functions[0].co_name != name:
        return "the module does not define one function of that name"
    if any(not isinstance(c, CodeType) and not _plain_constant(c) for c in code.co_consts):
        return "the module holds a constant outside the vocabulary"
    fn = functions[0]
    if fn.co_freevars or fn.co_cellvars:
        return "the function has a closure"
    if not set(fn.co_names) <= ATTRIBUTES:
        return f"the function reads {sorted(set(fn.co_names) - ATTRIBUTES)}"
    for local in fn.co_varnames:
        if not (local in LOCALS or _HANDED.match(local)):
            return f"the function has the local {local!r}"
    for constant in fn.co_consts:
        if not _plain_constant(constant):
            return f"the function holds the constant {constant!r}"
    return None


def _plain_constant(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int)):
        return True
    return isinstance(value, tuple) and all(_plain_constant(v) for v in value)


def code_table() -> dict[tuple[str, str], CodeType]:
    """The compiled code by (text, file name) that :func:`build` keeps, every text checked by
    :func:`_check` before it was compiled: the HMI's start keeps it across processes
    (hmi.codecache.kept_codes, under a fingerprint of this module's source), and an entry
    not compiled in this process is checked (:func:`check_code`) before it first runs."""
    return _CODE


# A past image read in an expression (expr_source), for the first four of them.
_PAST_READ = re.compile(r"\bh\[([0-3])\]\[")


def _bind_past(lines: list[str]) -> list[str]:
    """`lines` with each past image they read at least twice (``h[0][5]``, ``h[0][7]``)
    bound once, on the function's first line (``h0 = h[0]``, then ``h0[5]``): the history is
    a deque, and a deque's item is a generic subscript (some 150 instructions, a local some
    10), where an image's slot is a tuple's. The history always holds as many images as the
    deepest expression reads (Engine._start fills it), so the binding reads what each use
    read, once; a past image read once is left where it is (a short-circuit may skip it)."""
    body = "\n".join(lines)
    counts: dict[str, int] = {}
    for depth in _PAST_READ.findall(body):
        counts[depth] = counts.get(depth, 0) + 1
    bound = sorted(depth for depth, count in counts.items() if count > 1)
    if not bound:
        return lines
    body = _PAST_READ.sub(lambda m: f"h{m.group(1)}[" if m.group(1) in bound else m.group(0),
                          body)
    return ["    " + "; ".join(f"h{depth} = h[{depth}]" for depth in bound),
            *body.split("\n")]


def build(source: Source, name: str, params: str, filename: str) -> Callable[..., Any]:
    """Compile `source`'s lines as the body of ``def name(params, k0=k0, ...)`` (past images
    read more than once bound first, when `params` has the history ``h``: _bind_past)."""
    lines = source.lines
    if "h" in (param.strip() for param in params.split(",")):
        lines = _bind_past(lines)
    # the objects' defaults follow the parameters; with none, they are the whole signature
    signature = ", ".join(part for part in (params, source.defaults().removeprefix(", "))
                          if part)
    text = f"def {name}({signature}):\n" + "\n".join(lines) + "\n"
    if not source.lines:
        text += "    pass\n"
    key = (text, filename)
    code = _CODE.get(key)
    if code is not None and _CHECKED.get(key) is not code:
        # kept by an earlier process (hmi.codecache.kept_codes): what runs is this code
        # object, so it is checked, not the text it is filed under
        if check_code(code, name) is None:
            _CHECKED[key] = code
        else:  # not code this module writes: compiled again from the checked text
            code = None
    if code is None:
        tree = ast.parse(text, filename=filename)
        _check(tree)
        if len(_CODE) >= CODE_CACHE:
            _CODE.clear()
            _CHECKED.clear()
        code = _CODE[key] = _CHECKED[key] = compile(tree, filename, "exec")
    namespace: dict[str, Any] = {"__builtins__": {}}
    namespace.update((f"k{n}", obj) for n, obj in enumerate(source.objects))
    exec(code, namespace)  # compiled from a tree checked above
    fn: Callable[..., Any] = namespace[name]
    fn.__doc__ = text  # what was generated, for whoever debugs it
    return fn
