"""A proof, with z3, that one call of an exported function block, as blark parses it, does
what the engine does, for every input and every state.

The exported Structured Text is parsed by blark (an independent IEC 61131-3 parser); its
syntax tree is executed symbolically (:class:`Symbolic`): every input and every variable the
block keeps between calls starts as an unconstrained z3 value, so the result is a formula of
them. BOOL is a z3 Bool, WORD/DWORD/LWORD a bit-vector of their width, INT/DINT a
mathematical integer (the values the block computes are small counts and indices; an
overflow is not modelled). Terms are folded as they are built, so a concrete value is a
literal. IF merges its branches (z3 If); FOR and WHILE are unrolled: a loop condition that is
not a constant keeps both worlds (the loop goes on under the condition, stops under its
negation) and, past UNCHECKED passes, asks z3 which of them the path allows (no bound is
assumed: a loop still running after LOOP_LIMIT iterations fails the proof); EXIT leaves the
loop in the world where it runs, and the next pass starts from the world where it did not.
A constant index out of bounds ends its path (:class:`Dead`): z3 is asked whether some input
and state take that path; when one does, the path's negation is an obligation (the bounds
property then fails with that path as counterexample), and when none does, the branch that led
there is dropped. A symbolic index is an obligation under its path condition.

A *split* variable (the filter's set of free outputs) is pinned to a constant where it is
read: when the case's assumptions leave it several values, the run is started again once per
value z3 finds (every one, until none is left: the cases cover every input and state), so the
loops it bounds (the corrector's search over k-subsets) run concretely. A property is proved
when it is valid in every case, under that case's assumption. The property is checked valid
by z3 (its negation unsatisfiable); a counterexample is printed when it is not.

`prove_filter` states the engine's safety filter (hmi/engine/filter.py, docs/filter.md) from
the project's constraints directly, not from the exporter: the violation word, the block
latch, the masks, the F0/F1 forcing and conflict, and the exact corrector's unique answer
(the safe vector at minimum Hamming distance over the unforced outputs, then fewest outputs
switched on, then the outputs declared first spared), or the safe state when that vector is
farther than MAX_DISTANCE.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import cache
from typing import Any, Protocol, TypeVar

import z3

LOOP_LIMIT = 2000
UNCHECKED = 64
BITS = {"BOOL": 1, "BYTE": 8, "WORD": 16, "DWORD": 32, "LWORD": 64}
INTS = ("SINT", "INT", "DINT", "LINT", "UINT", "UDINT", "USINT")
TIME_MS = {"days": 86_400_000, "hours": 3_600_000, "minutes": 60_000, "seconds": 1000,
           "milliseconds": 1}


class Unsupported(Exception):
    """A construct the symbolic executor does not model: the proof is not claimed."""


class Dead(Exception):
    """The path being executed ends here: z3 found it infeasible (no input and state take
    it), or it indexes an array out of bounds on a feasible path (recorded as a failed
    obligation, with the path as counterexample: a PLC stops there with a run-time fault).
    The innermost branch that extended the path condition catches it and keeps its other
    world."""


class SplitPass(Exception):
    """A branch on a value the call found in its state (see Symbolic.stale) inside a WHILE,
    both ways possible: the WHILE's pass is run again in each world, each to the end of the
    loop, and only then merged."""

    def __init__(self, cond: Any):
        super().__init__("a branch on a kept value")
        self.cond = cond


class NeedSplit(Exception):
    """A split variable read while the case's assumptions leave it several values."""

    def __init__(self, value: Any):
        super().__init__("a split value")  # (not the term: printing it costs seconds)
        self.value = value


@dataclass(frozen=True)
class VarType:
    name: str  # BOOL, DWORD, INT, ...
    low: int | None = None  # an array's bounds
    high: int | None = None


@dataclass
class Declared:
    """A function block's variables: sections, types, the constants' values (as z3 terms)."""

    types: dict[str, VarType] = field(default_factory=dict)
    sections: dict[str, str] = field(default_factory=dict)
    constants: dict[str, Any] = field(default_factory=dict)
    order: list[str] = field(default_factory=list)


class BlockModel(Protocol):
    """What a call of a function block instance does, for a program that calls it (a
    PROGRAM's `Inst(Port := value, ...)` and its reads `Inst.Out`): the block's variables
    (inputs, outputs and locals: an instance keeps them all between calls, an input a call
    does not give keeps its last value), the globals it reads and those it writes
    (VAR_EXTERNAL), and one call: the instance's variables and the globals it reads before,
    its variables and the globals it writes after."""

    variables: dict[str, VarType]
    reads: tuple[str, ...]
    writes: tuple[str, ...]

    def call(self, variables: dict[str, Any], globals_: dict[str, Any]
             ) -> tuple[dict[str, Any], dict[str, Any]]: ...


# --------------------------------------------------------------------------------------------
# blark
# --------------------------------------------------------------------------------------------


@cache
def _parser() -> Any:
    from blark.parse import new_parser
    return new_parser()


def pou_text(text: str, name: str) -> str:
    """The text of FUNCTION_BLOCK `name` in an exported file."""
    start = re.search(rf"^FUNCTION_BLOCK {re.escape(name)}\s*$", text, re.MULTILINE)
    if start is None:
        raise KeyError(name)
    end = text.index("END_FUNCTION_BLOCK", start.start()) + len("END_FUNCTION_BLOCK")
    return text[start.start():end] + "\n"


def parse_fb(text: str) -> Any:
    """blark's tree of the one function block in `text` (an error if blark refuses it)."""
    from blark.parse import parse_source_code
    result = parse_source_code(text, parser=_parser())
    if result.exception is not None:
        raise SyntaxError(f"blark: {result.exception}")
    items = result.transform().items
    assert len(items) == 1, items
    return items[0]


@cache
def _parsed(text: str) -> Any:
    return parse_fb(text)


def parse_changed(original: str, changed: str) -> Any:
    """blark's tree of `changed`, a function block that differs from `original` within one
    line (a mutant, a tampered block): the original's tree (parsed once) with the node that
    holds the change parsed again on its own (blark's Earley parser takes seconds on a block
    of a thousand lines, a line takes milliseconds). The node is the largest one that lies
    on that line and covers the change (a one-line statement, a condition, a CASE label);
    when there is none, the whole block is parsed."""
    import dataclasses
    old_lines, new_lines = original.splitlines(), changed.splitlines()
    differ = [k for k, (a, b) in enumerate(zip(old_lines, new_lines, strict=False)) if a != b]
    if len(old_lines) != len(new_lines) or len(differ) != 1:
        return parse_fb(changed)
    k = differ[0]
    old, new = old_lines[k], new_lines[k]
    head = len(_common_prefix(old, new))
    tail = len(_common_prefix(old[head:][::-1], new[head:][::-1]))
    line = k + 1
    tree = _parsed(original)
    # (width, the path to the node: (field, index) from the root)
    best: tuple[int, tuple[tuple[str, int | None], ...]] | None = None
    from blark import transform as tf

    def covers(node: Any) -> bool:
        if not isinstance(node, tf.Statement | tf.Expression):
            return False
        meta = getattr(node, "meta", None)
        if meta is None or getattr(meta, "line", None) != line or meta.end_line != line:
            return False
        return meta.column - 1 <= head and len(old) - tail <= meta.end_column - 1

    def visit(node: Any, path: tuple[tuple[str, int | None], ...]) -> None:
        nonlocal best
        if not dataclasses.is_dataclass(node):
            return
        meta = getattr(node, "meta", None)
        if meta is not None and getattr(meta, "line", None) is not None and not (
                meta.line <= line <= meta.end_line):
            return  # (the change is not under this node)
        for f in dataclasses.fields(node):
            value = getattr(node, f.name)
            items = list(enumerate(value)) if isinstance(value, list) else [(None, value)]
            for index, child in items:
                here = (*path, (f.name, index))
                if covers(child):
                    width = child.meta.end_column - child.meta.column
                    if best is None or width > best[0]:
                        best = (width, here)
                visit(child, here)

    visit(tree, ())
    if best is None:
        return parse_fb(changed)
    node = tree
    for name, index in best[1]:
        node = getattr(node, name) if index is None else getattr(node, name)[index]
    start, end = node.meta.column - 1, node.meta.end_column - 1 + len(new) - len(old)
    piece = new[start:end]
    statement = isinstance(node, tf.Statement)
    try:
        body = parse_fb("FUNCTION_BLOCK F\n" + (piece if statement else f"X := {piece};")
                        + "\nEND_FUNCTION_BLOCK\n").body
    except SyntaxError:
        body = None
    wrapped = body.statements if body is not None else []  # (none: a statement removed)
    if len(wrapped) != 1:
        return parse_fb(changed)
    return _replaced(tree, best[1], wrapped[0] if statement else wrapped[0].expression)


def _replaced(node: Any, path: tuple[tuple[str, int | None], ...], replacement: Any) -> Any:
    """`node` with the node at `path` replaced: the nodes on the path copied, the rest
    shared with the original tree (which is cached: never changed)."""
    import copy
    if not path:
        return replacement
    (name, index), rest = path[0], path[1:]
    new = copy.copy(node)
    if index is None:
        setattr(new, name, _replaced(getattr(node, name), rest, replacement))
    else:
        items = list(getattr(node, name))
        items[index] = _replaced(items[index], rest, replacement)
        setattr(new, name, items)
    return new


def _common_prefix(a: str, b: str) -> str:
    n = 0
    while n < min(len(a), len(b)) and a[n] == b[n]:
        n += 1
    return a[:n]


def _type(spec: Any) -> VarType:
    from blark import transform as tf
    if isinstance(spec, tf.ArraySpecification):
        (sub,) = spec.subranges
        base = _type_name(spec.type)
        return VarType(base, int(str(sub.start)), int(str(sub.stop)))
    return VarType(_type_name(spec))


def _type_name(spec: Any) -> str:
    text = str(getattr(spec, "type", spec))
    return text.strip().upper()


def declarations(fb: Any) -> Declared:
    from blark import transform as tf
    out = Declared()
    section_of = {tf.InputDeclarations: "input", tf.OutputDeclarations: "output",
                  tf.VariableDeclarations: "local", tf.ExternalVariableDeclarations: "external"}
    for block in fb.declarations:
        section = section_of.get(type(block))
        if section is None:
            raise Unsupported(f"declarations {type(block).__name__}")
        constant = "CONSTANT" in str(block.attrs or "").upper()
        for item in block.items:
            if isinstance(item, tf.ExternalVariableDeclaration):  # (one name, no value)
                name = str(item.name).upper()
                out.types[name] = _type(item.spec)
                out.sections[name] = section
                out.order.append(name)
                continue
            init = item.init
            vtype = _type(init.spec)
            for v in item.variables:
                name = str(getattr(v, "name", v)).upper()
                out.types[name] = vtype
                out.sections[name] = "constant" if constant else section
                out.order.append(name)
                if constant:
                    out.constants[name] = _constant(init.value, vtype)
    return out


def _flat(init: Any) -> list[Any]:
    """An array initialisation's elements in order (blark nests `[a, b, c]` as a, then the
    rest as an initialisation of its own; `n(x)` repeats x n times)."""
    from blark import transform as tf
    out: list[Any] = []
    for e in init.elements:
        element = getattr(e, "element", e)
        items = _flat(element) if isinstance(element, tf.ArrayInitialization) else [element]
        count = getattr(e, "count", None)
        out += items * (int(str(count)) if count is not None else 1)
    return out


def _constant(value: Any, vtype: VarType) -> Any:
    from blark import transform as tf
    ex = Symbolic.literal_of
    if vtype.low is not None:
        assert isinstance(value, tf.ArrayInitialization), value
        items = [ex(e, vtype.name) for e in _flat(value)]
        assert len(items) == vtype.high - vtype.low + 1, (len(items), vtype)  # type: ignore[operator]
        return items
    return ex(value, vtype.name)


# --------------------------------------------------------------------------------------------
# Symbolic execution
# --------------------------------------------------------------------------------------------


def _fresh(name: str, vtype: str) -> Any:
    if vtype == "BOOL":
        return z3.Bool(name)
    if vtype in BITS:
        return z3.BitVec(name, BITS[vtype])
    if vtype in INTS or vtype == "TIME":  # (TIME: integer milliseconds)
        return z3.Int(name)
    raise Unsupported(f"type {vtype}")


def _literal(ctx: Any, ast: Any) -> bool:
    """A numeral, TRUE or FALSE (z3's C API asked directly: the Python predicates cost a
    dozen calls each, and the executor asks this of every term it builds)."""
    kind = z3.Z3_get_ast_kind(ctx, ast)
    if kind == z3.Z3_NUMERAL_AST:
        return True
    if kind != z3.Z3_APP_AST:
        return False
    op = z3.Z3_get_decl_kind(ctx, z3.Z3_get_app_decl(ctx, ast))
    return bool(op == z3.Z3_OP_TRUE or op == z3.Z3_OP_FALSE)


# Each term's folded form and its Python value (None: not a constant), by the address of
# its z3 AST (the term is kept with them, so the address names that term while the entry
# lives): the executor folds and tests the same terms over and over (a loop's bound, an
# index, a condition, on every pass and path), and asking z3 again costs a dozen C calls
# through ctypes each time.
_FOLDED: dict[int, tuple[Any, Any, Any]] = {}
_FOLDED_MAX = 1 << 20


def _folded(v: Any) -> tuple[Any, Any, Any]:
    key = v.ast.value
    hit = _FOLDED.get(key)
    if hit is not None:
        return hit
    out = v
    ctx, ast = v.ctx_ref(), v.ast
    if z3.Z3_get_ast_kind(ctx, ast) == z3.Z3_APP_AST and not _literal(ctx, ast):
        count = z3.Z3_get_app_num_args(ctx, ast)
        if count and all(_literal(ctx, z3.Z3_get_app_arg(ctx, ast, k))
                         for k in range(count)):
            out = z3.simplify(v)
    value: Any = None
    if z3.is_true(out):
        value = True
    elif z3.is_false(out):
        value = False
    elif z3.is_int_value(out) or z3.is_bv_value(out):
        value = out.as_long()
    if len(_FOLDED) >= _FOLDED_MAX:
        _FOLDED.clear()
    entry = _FOLDED[key] = (v, out, value)
    return entry


def _fold(v: Any) -> Any:
    """`v` as a literal when its operands are literals (terms are folded as they are built,
    so a value is concrete exactly when it is a literal: no walk over a large term)."""
    return _folded(v)[1]


def _ite(cond: Any, yes: Any, no: Any) -> Any:
    """z3's If, folded when the condition is a literal or both sides are the same term."""
    known = _concrete(cond)
    if known is not None:
        return yes if known else no
    return yes if yes.eq(no) else z3.If(cond, yes, no)


def _concrete(value: Any) -> Any:
    """A Python bool/int when `value` is a constant, else None."""
    return _folded(value)[2]


EXIT = "$exit"


class Symbolic:
    """One call of a function block on symbolic inputs and state (`runs`: blocks of
    statements run before, reused)."""

    runs: KeptRuns | None = None

    def __init__(self, fb: Any, initial: dict[str, Any] | None = None,
                 loop_limit: int = LOOP_LIMIT, split: frozenset[str] = frozenset(),
                 assume: tuple[Any, ...] = (), unchecked: int = UNCHECKED,
                 blocks: dict[str, BlockModel] | None = None,
                 stale: frozenset[str] = frozenset()):
        # (`blocks`: the function blocks a program's instances are of, by type name in upper
        # case; an instance's variable V is the state's "INST.V"; `stale`: variables whose
        # values as the call found them a branch inside a WHILE splits the pass on, see
        # _split_pass)
        self.fb = fb
        self.blocks = {k.upper(): v for k, v in (blocks or {}).items()}
        self.loop_limit = loop_limit
        self.unchecked = unchecked
        self.decl = declarations(fb)
        self.solver = z3.Solver()
        self.solver.add(*assume)
        self.assume = assume
        self.split = split
        self.pinned: dict[int, Any] = {}
        self.target: str | None = None
        self.checks = 0
        self.pc: list[Any] = []  # the path condition of the statement being executed
        state: dict[str, Any] = {}
        for name in self.decl.order:
            t = self.decl.types[name]
            if self.decl.sections[name] == "constant":
                state[name] = self.decl.constants[name]
            elif t.name in self.blocks and t.low is None:
                for var, vt in self.blocks[t.name].variables.items():
                    state[f"{name}.{var}"] = (
                        [_fresh(f"{name}.{var}[{k}]", vt.name)
                         for k in range(vt.low, vt.high + 1)]  # type: ignore[operator]
                        if vt.low is not None else _fresh(f"{name}.{var}", vt.name))
            elif t.low is not None:
                state[name] = [_fresh(f"{name}[{k}]", t.name)
                               for k in range(t.low, t.high + 1)]  # type: ignore[operator]
            else:
                state[name] = _fresh(name, t.name)
        state.update({k.upper(): v for k, v in (initial or {}).items()})
        state[EXIT] = z3.BoolVal(False)
        self.initial = dict(state)
        self.stale = {x.get_id() for name in stale
                      for x in (state[name] if isinstance(state[name], list) else [state[name]])}
        self._mentions: dict[int, tuple[Any, bool, bool]] = {}
        self.whiles = 0  # the WHILE loops the statement being executed is in

    def run(self) -> dict[str, Any]:
        try:
            return self.block(self.fb.body.statements, dict(self.initial), [])
        except Dead:  # (every path ends: the assumptions are infeasible, or an obligation
            return dict(self.initial)  # failed on a path that always faults)

    def _live(self, run: Callable[[], dict[str, Any]]) -> dict[str, Any] | None:
        """`run()`, a branch under an extended path condition; None when it is dead."""
        try:
            return run()
        except Dead:
            return None

    # -- values --------------------------------------------------------------------------------
    @staticmethod
    def literal_of(node: Any, want: str | None = None) -> Any:
        from blark import transform as tf
        if isinstance(node, tf.Boolean):
            return z3.BoolVal(str(node.value).upper() == "TRUE")
        if isinstance(node, tf.Integer | tf.HexBitString | tf.BinaryBitString
                      | tf.OctalBitString | tf.BitString):
            base = {tf.HexBitString: 16, tf.BinaryBitString: 2, tf.OctalBitString: 8
                    }.get(type(node), 10)
            value = int(str(node.value).replace("_", ""), base)
            tname = str(node.type_name).upper() if node.type_name else want
            if tname in BITS and tname != "BOOL":
                return z3.BitVecVal(value, BITS[tname])
            return z3.IntVal(value)
        if isinstance(node, tf.Duration):  # T#...: integer milliseconds
            from fractions import Fraction
            ms = sum(Fraction(str(getattr(node, unit)).replace("_", "")) * scale
                     for unit, scale in TIME_MS.items() if getattr(node, unit) is not None)
            if ms.denominator != 1:
                raise Unsupported(f"a TIME literal below the millisecond: {node}")
            return z3.IntVal(-ms.numerator if node.negative else ms.numerator)
        raise Unsupported(f"literal {type(node).__name__}: {node}")

    def value(self, node: Any, st: dict[str, Any]) -> Any:
        return _fold(self._value(node, st))

    def _value(self, node: Any, st: dict[str, Any]) -> Any:
        from blark import transform as tf
        if isinstance(node, tf.ParenthesizedExpression):
            return self.value(node.expr, st)
        if isinstance(node, tf.SimpleVariable):
            name = str(node.name).upper()
            v = st[name]
            if isinstance(v, list):
                raise Unsupported(f"a whole array {node.name}")
            if name in self.split and name != self.target:
                return self._pin(v)
            return v
        if isinstance(node, tf.MultiElementVariable) and self._instance(node.name):
            if len(node.elements) != 1 or not isinstance(node.elements[0], tf.FieldSelector):
                raise Unsupported(f"member access {node}")
            return st[f"{str(node.name).upper()}.{str(node.elements[0].field).upper()}"]
        if isinstance(node, tf.MultiElementVariable):
            array, index = self._element(node, st)
            return self._select(array, index, st, str(node.name))
        if isinstance(node, tf.UnaryOperation):
            inner = self.value(node.expr, st)
            op = str(node.op).upper()
            if op == "NOT":
                return z3.Not(inner) if z3.is_bool(inner) else ~inner
            if op == "-":
                return -inner
            raise Unsupported(f"unary {op}")
        if isinstance(node, tf.BinaryOperation):
            return self._binary(str(node.op).upper(), node.left, node.right, st)
        if isinstance(node, tf.FunctionCall):
            name = str(node.name).upper()
            args = [self.value(p.value, st) for p in node.parameters]
            if name == "SHL" and len(args) == 2:
                word, count = args
                return word << self._as_bv(count, word.size())
            raise Unsupported(f"function {name}")
        return self.literal_of(node)

    @staticmethod
    def _as_bv(value: Any, width: int) -> Any:
        if z3.is_int_value(value):
            return z3.BitVecVal(value.as_long(), width)
        return z3.Int2BV(value, width) if z3.is_int(value) else value

    def _binary(self, op: str, left: Any, right: Any, st: dict[str, Any]) -> Any:
        a, b = self.value(left, st), self.value(right, st)
        if z3.is_bv(a) and z3.is_int(b):
            b = self._as_bv(b, a.size())
        elif z3.is_bv(b) and z3.is_int(a):
            a = self._as_bv(a, b.size())
        if op in ("AND", "AND_THEN", "&"):
            if z3.is_bool(a):
                if z3.is_false(a) or z3.is_false(b):
                    return z3.BoolVal(False)
                return b if z3.is_true(a) else a if z3.is_true(b) else z3.And(a, b)
            return a & b
        if op in ("OR", "OR_ELSE"):
            if z3.is_bool(a):
                if z3.is_true(a) or z3.is_true(b):
                    return z3.BoolVal(True)
                return b if z3.is_false(a) else a if z3.is_false(b) else z3.Or(a, b)
            return a | b
        if op == "XOR":
            return z3.Xor(a, b) if z3.is_bool(a) else a ^ b
        if op == "=":
            return a == b
        if op == "<>":
            return a != b
        if op in ("<", "<=", ">", ">="):
            if z3.is_bv(a):
                return {"<": z3.ULT, "<=": z3.ULE, ">": z3.UGT, ">=": z3.UGE}[op](a, b)
            return {"<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b}[op]
        if op == "+":
            return a + b
        if op == "-":
            return a - b
        if op == "*":
            return a * b
        raise Unsupported(f"operator {op}")

    def _pin(self, v: Any) -> Any:
        """A split variable read (other than by its own update): its value as a constant, the
        one the case's assumptions leave it; when they leave it several, the case is split."""
        if _concrete(v) is not None:
            return v
        key = v.get_id()
        if key not in self.pinned:
            self.checks += 1
            self.solver.push()
            found = self.solver.check()
            if found != z3.sat:
                raise Unsupported(f"z3 could not pin a split value: {found}")
            c = self.solver.model().eval(v, model_completion=True)
            self.solver.add(v != c)
            unique = self.solver.check()
            self.solver.pop()
            if unique != z3.unsat:
                raise NeedSplit(v)
            self.pinned[key] = c
        return self.pinned[key]

    def _element(self, node: Any, st: dict[str, Any]) -> tuple[str, Any]:
        from blark import transform as tf
        if len(node.elements) != 1 or not isinstance(node.elements[0], tf.SubscriptList):
            raise Unsupported(f"member access {node}")
        (sub,) = node.elements[0].subscripts
        return str(node.name).upper(), self.value(sub, st)

    def _select(self, name: str, index: Any, st: dict[str, Any], shown: str) -> Any:
        items = st[name]
        low = self.decl.types[name].low or 0
        k = _concrete(index)
        if k is not None:
            if not low <= k < low + len(items):
                self._out_of_bounds(f"{shown}[{k}]")
            return items[k - low]
        out = items[-1]  # (an index out of bounds: the obligation below says it is not)
        for j in range(len(items) - 2, -1, -1):
            out = _ite(index == low + j, items[j], out)
        self._in_bounds(index, low, len(items), shown)
        return out

    def _in_bounds(self, index: Any, low: int, n: int, shown: str) -> None:
        self.obligations.append((z3.Implies(z3.And(*self.pc),
                                            z3.And(index >= low, index < low + n)),
                                 f"{shown} index in bounds"))

    def _out_of_bounds(self, shown: str) -> None:
        """A constant index out of bounds: the path ends (Dead); when some input and state
        take it, it is also an obligation that fails (the path is the counterexample)."""
        if self._feasible(self.pc, z3.BoolVal(True)):
            self.obligations.append((z3.Not(z3.And(*self.pc)), f"{shown} out of bounds"))
        raise Dead(shown)

    obligations: list[tuple[Any, str]]

    # -- statements ----------------------------------------------------------------------------
    def block(self, stmts: Any, st: dict[str, Any], pc: list[Any]) -> dict[str, Any]:
        if stmts is None:
            return st
        if self.runs is not None:
            return self.runs.block(self, stmts, st, pc)
        return self.statements(stmts, st, pc)

    def statements(self, stmts: Any, st: dict[str, Any], pc: list[Any]) -> dict[str, Any]:
        for s in getattr(stmts, "statements", stmts):
            leaving = _concrete(st[EXIT])
            if leaving is True:
                break
            if leaving is False:
                st = self.stmt(s, st, pc)
            else:
                inner = [*pc, z3.Not(st[EXIT])]
                on = self._live(lambda s=s, st=st, inner=inner: self.stmt(s, st, inner))
                st = st if on is None else merge(st[EXIT], st, on)
        return st

    def stmt(self, s: Any, st: dict[str, Any], pc: list[Any]) -> dict[str, Any]:
        from blark import transform as tf
        self.pc = pc
        if isinstance(s, tf.StatementList):
            return self.block(s.statements, st, pc)
        if isinstance(s, tf.AssignmentStatement):
            (target,) = s.variables
            self.target = str(getattr(target, "name", "")).upper()
            try:
                value = self.value(s.expression, st)
            finally:
                self.target = None
            return self.assign(target, value, st)
        if isinstance(s, tf.IfStatement):
            branches = [(s.if_expression, s.statements)]
            branches += [(e.if_expression, e.statements) for e in s.else_ifs]
            orelse = s.else_clause.statements if s.else_clause is not None else None
            return self._if(branches, orelse, st, pc)
        if isinstance(s, tf.ForStatement):
            return self._for(s, st, pc)
        if isinstance(s, tf.WhileStatement):
            return self._while(s, st, pc, 0)
        if isinstance(s, tf.ExitStatement):
            out = dict(st)
            out[EXIT] = z3.BoolVal(True)
            return out
        if isinstance(s, tf.CaseStatement):
            return self._case(s, st, pc)
        if isinstance(s, tf.FunctionCallStatement) and self._instance(s.name):
            return self._call(s, st)
        raise Unsupported(f"statement {type(s).__name__}")

    def _instance(self, node: Any) -> bool:
        """`node` names an instance of a function block in `blocks`."""
        t = self.decl.types.get(str(getattr(node, "name", node)).upper())
        return t is not None and t.low is None and t.name in self.blocks

    def _call(self, s: Any, st: dict[str, Any]) -> dict[str, Any]:
        """`Inst(Port := value, ...)`: the values (all read before any is given), the ports
        given them, then the block's call on the instance's variables and the globals it
        reads; an input not given keeps its value."""
        from blark import transform as tf
        inst = str(s.name.name).upper()
        model = self.blocks[self.decl.types[inst].name]
        given = []
        for p in s.parameters:
            if not isinstance(p, tf.InputParameterAssignment) or p.name is None:
                raise Unsupported(f"a call parameter {p}")
            port = str(p.name.name).upper()
            if port not in model.variables:
                raise Unsupported(f"{inst} has no port {port}")
            given.append((port, self.value(p.value, st)))
        out = dict(st)
        for port, value in given:
            out[f"{inst}.{port}"] = value
        variables = {v: out[f"{inst}.{v}"] for v in model.variables}
        after, written = model.call(variables, {g: out[g] for g in model.reads})
        for v in model.variables:
            out[f"{inst}.{v}"] = after[v]
        for g in model.writes:
            out[g] = written[g]
        return out

    def assign(self, target: Any, value: Any, st: dict[str, Any]) -> dict[str, Any]:
        from blark import transform as tf
        out = dict(st)
        if isinstance(target, tf.SimpleVariable):
            name = str(target.name).upper()
            if self.decl.sections.get(name) == "constant":
                raise Unsupported(f"assignment to the constant {name}")
            out[name] = value
            return out
        name, index = self._element(target, st)
        items = list(st[name])
        low = self.decl.types[name].low or 0
        k = _concrete(index)
        if k is not None:
            if not low <= k < low + len(items):
                self._out_of_bounds(f"{name}[{k}] :=")
            items[k - low] = value
        else:
            self._in_bounds(index, low, len(items), name)
            items = [_ite(index == low + j, value, item) for j, item in enumerate(items)]
        out[name] = items
        return out

    def _if(self, branches: list[tuple[Any, Any]], orelse: Any, st: dict[str, Any],
            pc: list[Any]) -> dict[str, Any]:
        if not branches:
            return self.block(orelse, st, pc) if orelse is not None else st
        (cond_node, body), rest = branches[0], branches[1:]
        self.pc = pc
        cond = self.value(cond_node, st)
        known = _concrete(cond)
        if known is None and self.whiles and self._on_stale(cond):
            known = self._split_pass(cond, pc)
        if known is True:
            return self.block(body, st, pc)
        if known is False:
            return self._if(rest, orelse, st, pc)
        yes = self._live(lambda: self.block(body, st, [*pc, cond]))
        no = self._live(lambda: self._if(rest, orelse, st, [*pc, z3.Not(cond)]))
        return self._either(cond, yes, no)

    @staticmethod
    def _either(cond: Any, yes: dict[str, Any] | None, no: dict[str, Any] | None
                ) -> dict[str, Any]:
        """The merge of two branches, a dead one left out (both dead: this path is too)."""
        if yes is None and no is None:
            raise Dead("both branches")
        if yes is None or no is None:
            return no if yes is None else yes  # type: ignore[return-value]
        return merge(cond, yes, no)

    def _case(self, s: Any, st: dict[str, Any], pc: list[Any]) -> dict[str, Any]:
        self.pc = pc
        selector = self.value(s.expression, st)
        branches = []
        for case in s.cases:
            tests = [selector == self.literal_of(m) for m in case.matches]
            branches.append((z3.Or(*tests), case.statements))
        orelse = s.else_clause.statements if s.else_clause is not None else None
        return self._if_values(branches, orelse, st, pc)

    def _if_values(self, branches: list[tuple[Any, Any]], orelse: Any, st: dict[str, Any],
                   pc: list[Any]) -> dict[str, Any]:
        if not branches:
            return self.block(orelse, st, pc) if orelse is not None else st
        (cond, body), rest = branches[0], branches[1:]
        known = _concrete(cond)
        if known is True:
            return self.block(body, st, pc)
        if known is False:
            return self._if_values(rest, orelse, st, pc)
        return self._either(
            cond, self._live(lambda: self.block(body, st, [*pc, cond])),
            self._live(lambda: self._if_values(rest, orelse, st, [*pc, z3.Not(cond)])))

    def _on_stale(self, term: Any) -> bool:
        """`term` reads values of `stale` as the call found them, and nothing else the call
        was given (e.g. `Comb[3] < 4`; not a test of Found once merged worlds left it a term
        over both: that is merged as any branch). Each term's answer kept with the term (an
        id names a term only while it lives), terms share their parts."""
        seen = self._mentions
        todo = [term]
        while todo:  # (post-order without recursion: the terms are deep)
            t = todo[-1]
            key = t.get_id()
            if key in seen:
                todo.pop()
                continue
            children = t.children()
            left = [c for c in children if c.get_id() not in seen]
            if left:
                todo += left
                continue
            todo.pop()
            if children:
                flags = (any(seen[c.get_id()][1] for c in children),
                         any(seen[c.get_id()][2] for c in children))
            elif _literal(t.ctx_ref(), t.as_ast()):
                flags = (False, False)
            else:
                flags = (key in self.stale, key not in self.stale)
            seen[key] = (t, *flags)
        _term, stale, other = seen[term.get_id()]
        return stale and not other

    def _split_pass(self, cond: Any, pc: list[Any]) -> bool:
        """A branch on a stale value inside a WHILE: the way the path takes, if only one is
        possible; else SplitPass (merged here, the two worlds would leave the loop's later
        passes out of step, e.g. one world counting up a stale Comb element while the other
        steps to the next subset: every index after it a term over both). Asked of the
        assumptions and path conditions on stale values alone (small, where the whole path
        condition is large): a way they exclude, the whole path excludes; a world they keep
        that the whole path excludes is run in vain but merged under a condition that never
        holds, which is sound."""
        known = [c for c in (*self.assume, *pc) if self._on_stale(c)]
        go, stop = self._satisfiable(*known, cond), self._satisfiable(*known, z3.Not(cond))
        if go and stop:
            raise SplitPass(cond)
        if not go and not stop:
            raise Dead("both branches")
        return go

    def _feasible(self, pc: list[Any], cond: Any) -> bool:
        """Some input and state take this path with `cond` (asked as :func:`_decided` asks:
        bit-blasted first, which answers most path checks several times faster)."""
        return self._satisfiable(*self.assume, *pc, cond)

    def _satisfiable(self, *formulas: Any) -> bool:
        self.checks += 1
        found, _solver = _decided(z3.And(*formulas))
        if found == z3.unknown:
            raise Unsupported("z3 could not decide a path condition")
        return bool(found == z3.sat)

    def _decide(self, cond: Any, pc: list[Any], count: int) -> bool | None:
        """True/False when the loop condition is fixed on this path, None when both worlds
        are possible. For the first UNCHECKED passes of a loop, a symbolic condition is not
        put to z3: both worlds are kept (a world the path excludes is merged under a
        condition that never holds there: sound, and cheaper than the question while the
        loop's own bound ends it)."""
        known = _concrete(cond)
        if known is not None:
            return bool(known)
        if count < self.unchecked:
            return None
        go, stop = self._feasible(pc, cond), self._feasible(pc, z3.Not(cond))
        if go and stop:
            return None
        return go

    def _for(self, s: Any, st: dict[str, Any], pc: list[Any]) -> dict[str, Any]:
        self.pc = pc
        control = s.control
        name = str(getattr(control, "name", control)).upper()
        first = self.value(s.from_, st)
        step = _concrete(self.value(s.step, st)) if s.step is not None else 1
        if step is None or step == 0:
            raise Unsupported("a FOR step that is not a constant")
        st = dict(st)
        st[name] = first
        return self._for_rest(name, s, step, st, pc, 0)

    def _for_rest(self, name: str, s: Any, step: int, st: dict[str, Any], pc: list[Any],
                  count: int) -> dict[str, Any]:
        return self._loop(s, st, pc, count, name, step)

    def _loop(self, s: Any, st: dict[str, Any], pc: list[Any], count: int, name: str | None,
              step: int) -> dict[str, Any]:
        """The rest of a FOR loop (control variable `name`, stepped by `step`) or of a WHILE
        (`name` None), from pass `count` on."""
        while True:
            self.pc = pc
            if name is None:
                cond = self.value(s.expression, st)
            else:
                last = self.value(s.to, st)
                cond = _fold(st[name] <= last if step > 0 else st[name] >= last)
            decided = self._decide(cond, pc, count)
            if decided is False:
                return st
            if count > self.loop_limit:
                loop = "WHILE" if name is None else f"FOR {name}"
                raise Unsupported(f"{loop} runs more than {self.loop_limit} times")
            try:  # (a split of this pass; the later passes' are taken by _left's own _loop)
                if decided is None:  # the loop goes on under cond, stops under its negation
                    on = self._live(lambda st=st, count=count, cond=cond: self._left(
                        s, self._pass(s, st, [*pc, cond], name), [*pc, cond], count, name,
                        step))
                    return st if on is None else merge(cond, on, st)
                after = self._pass(s, st, pc, name)
            except SplitPass as split:
                return self._split(split, s, st, pc, count, name, step)
            if _concrete(after[EXIT]) is False:  # the loop goes on, on this path
                st, count = self._stepped(after, name, step), count + 1
                continue
            return self._left(s, after, pc, count, name, step)

    def _split(self, split: SplitPass, s: Any, st: dict[str, Any], pc: list[Any], count: int,
               name: str | None, step: int) -> dict[str, Any]:
        """The rest of a WHILE from pass `count`, once in each world of the branch (a FOR
        leaves the split to the WHILE it is in)."""
        if name is not None:
            raise split
        return self._either(split.cond, *[
            self._live(lambda side=side: self._loop(s, st, [*pc, side], count, name, step))
            for side in (split.cond, z3.Not(split.cond))])

    def _pass(self, s: Any, st: dict[str, Any], pc: list[Any], name: str | None
              ) -> dict[str, Any]:
        """One pass of a loop's body (a WHILE's counted in `whiles`)."""
        if name is not None or not self.stale:
            return self.block(s.statements, st, pc)
        self.whiles += 1
        try:
            return self.block(s.statements, st, pc)
        finally:
            self.whiles -= 1

    def _left(self, s: Any, after: dict[str, Any], pc: list[Any], count: int,
              name: str | None, step: int) -> dict[str, Any]:
        """The loop after pass `count` ran to `after`: left by its EXIT, or going on, or
        (a symbolic EXIT) both, the rest of the loop under the EXIT not taken."""
        left = _concrete(after[EXIT])
        if left is True:
            return self._spent(after)
        on = self._stepped(after, name, step)
        if left is False:
            return self._loop(s, on, pc, count + 1, name, step)
        rest = self._live(lambda: self._loop(s, on, [*pc, z3.Not(after[EXIT])], count + 1,
                                             name, step))
        return self._spent(after) if rest is None else merge(after[EXIT], self._spent(after),
                                                            rest)

    @staticmethod
    def _stepped(after: dict[str, Any], name: str | None, step: int) -> dict[str, Any]:
        """The state the next pass starts from, where the body did not leave the loop: the
        EXIT not taken and (FOR) the control variable stepped. (Where the body left, the
        other world, the control variable stays as it was: :meth:`_spent`.)"""
        on = dict(after)
        on[EXIT] = z3.BoolVal(False)
        if name is not None:
            on[name] = _fold(after[name] + step)
        return on

    @staticmethod
    def _spent(after: dict[str, Any]) -> dict[str, Any]:
        """The state after an EXIT: the loop left, the EXIT spent."""
        out = dict(after)
        out[EXIT] = z3.BoolVal(False)
        return out

    def _while(self, s: Any, st: dict[str, Any], pc: list[Any], count: int
               ) -> dict[str, Any]:
        return self._loop(s, st, pc, count, None, 0)


def _id(value: Any) -> Any:
    if isinstance(value, z3.AstRef):
        return value.get_id()
    if isinstance(value, list):
        return tuple(_id(v) for v in value)
    return value


def _lines(stmts: Any) -> int:
    """How many lines a block of statements spans (0: unknown)."""
    items = getattr(stmts, "statements", stmts)
    if not items:
        return 0
    first, last = getattr(items[0], "meta", None), getattr(items[-1], "meta", None)
    if first is None or last is None or first.line is None or last.end_line is None:
        return 0
    return int(last.end_line - first.line + 1)


@dataclass
class KeptRuns:
    """The blocks of statements (of at least LINES lines) one run of a function block ran,
    each with the state and path it started from, what it left and the obligations it
    added (or the Dead it ended in), reused by the runs of its mutants: parse_changed's
    tree shares every node the change is not under, and a z3 term is the same object
    whenever it is the same term, so a block the change is not under, started from the
    same state on the same path, leaves what it left (a diagnoser's three modes: the two
    the change is not in are not run again). `recording`: the original's run, which keeps
    them (a mutant's own blocks are not kept)."""

    LINES = 10
    recording: bool = True
    kept: dict[tuple[Any, ...], tuple[Any, ...]] = field(default_factory=dict)
    sizes: dict[int, tuple[Any, int]] = field(default_factory=dict)
    hits: int = 0

    def block(self, sym: Symbolic, stmts: Any, st: dict[str, Any], pc: list[Any]
              ) -> dict[str, Any]:
        size = self.sizes.get(id(stmts))
        if size is None or size[0] is not stmts:
            if not self.recording:
                return sym.statements(stmts, st, pc)
            size = self.sizes[id(stmts)] = (stmts, _lines(stmts))
        if size[1] < self.LINES:
            return sym.statements(stmts, st, pc)
        key = (id(stmts), tuple((k, _id(v)) for k, v in st.items()),
               tuple(c.get_id() for c in pc))
        hit = self.kept.get(key)
        if hit is not None and hit[0] is stmts:
            self.hits += 1
            _stmts, _held, out, obligations, dead = hit
            sym.obligations.extend(obligations)
            if dead is not None:
                raise Dead(dead)
            return dict(out)
        if not self.recording:
            return sym.statements(stmts, st, pc)
        before = len(sym.obligations)
        try:
            out = sym.statements(stmts, st, pc)
        except Dead as end:
            self.kept[key] = (stmts, (st, pc), None, sym.obligations[before:], str(end))
            raise
        self.kept[key] = (stmts, (st, pc), dict(out), sym.obligations[before:], None)
        return out


def merge(cond: Any, yes: dict[str, Any], no: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for key, a in yes.items():
        b = no[key]
        if a is b:
            out[key] = a
        elif isinstance(a, list):
            out[key] = [_ite(cond, x, y) for x, y in zip(a, b, strict=True)]
        else:
            out[key] = _ite(cond, a, b)
    return out


def execute(fb: Any, loop_limit: int = LOOP_LIMIT) -> tuple[Symbolic, dict[str, Any]]:
    sym = Symbolic(fb, loop_limit=loop_limit)
    sym.obligations = []
    return sym, sym.run()


@dataclass(frozen=True)
class Case:
    """One run of the block under assumptions over its inputs and state (a case of a split):
    the cases of a split cover every input and state, so a property valid in each case is
    valid."""

    assume: tuple[Any, ...]
    sym: Symbolic
    out: dict[str, Any]


def execute_cases(fb: Any, split: frozenset[str], loop_limit: int = LOOP_LIMIT,
                  assume: tuple[Any, ...] = (), unchecked: int = UNCHECKED,
                  stale: frozenset[str] = frozenset()) -> list[Case]:
    """Runs of `fb`, one per value of the split variables where the block reads them: a run
    that reads a split variable with several possible values is started again once per
    value (every value z3 finds under the assumptions, then none left: the cases are
    exhaustive), so the loops those variables bound run concretely."""
    sym = Symbolic(fb, loop_limit=loop_limit, split=split, assume=assume, unchecked=unchecked,
                   stale=stale)
    sym.obligations = []
    try:
        out = sym.run()
    except NeedSplit as need:
        values = []
        solver = z3.Solver()
        solver.add(*assume)
        while (found := solver.check()) != z3.unsat:
            if found != z3.sat:
                raise Unsupported(f"z3 could not enumerate a split value: {found}") from None
            c = solver.model().eval(need.value, model_completion=True)
            values.append(c)
            solver.add(need.value != c)
            if len(values) > 4096:
                raise Unsupported("more than 4096 cases of a split value") from None
        return [case for c in values
                for case in execute_cases(fb, split, loop_limit, (*assume, need.value == c),
                                          unchecked, stale)]
    return [Case(assume, sym, out)]


# --------------------------------------------------------------------------------------------
# The filter's specification: the engine's, from the project
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FilterWiring:
    """Which identifier of the filter FB stands for what (the exporter's naming: a wrong
    wiring inside the block shows as a failed proof, since the specification reads the
    project values through these names)."""

    inputs: dict[tuple[str, int], str]  # (project name, depth) -> FB input
    outputs: dict[str, str]  # project output -> FB output
    ports: dict[str, str]  # role (Policy, Reset, Ftc, Violations, Latched, Fallback, FOV_x)


def filter_wiring(project: Any) -> tuple[str, FilterWiring]:
    """The filter FB's name and wiring, as the export builds it (hmi.export.stage_blocks)."""
    ((_args, block),) = built_blocks(project, "build_filter", "hmi.export.stage_blocks")
    up = str.upper
    return block.pou.name, FilterWiring({k: up(v) for k, v in block.inputs.items()},
                                        {k: up(v) for k, v in block.outputs.items()},
                                        {k: up(v) for k, v in block.ports.items()})


# What a study keeps while `builds_kept()` is active (it judges thousands of mutants of one
# export): (id(project), key) -> (the project, held so that its id stays its own, the value).
_KEPT: dict[tuple[Any, ...], tuple[Any, Any]] | None = None
T = TypeVar("T")


@contextmanager
def builds_kept() -> Iterator[None]:
    """Within it, what `kept` is asked is made once per project (each project's export
    built once per builder, the program's side of a proof lowered once): the projects
    must not change meanwhile."""
    global _KEPT
    saved, _KEPT = _KEPT, {} if _KEPT is None else _KEPT
    try:
        yield
    finally:
        _KEPT = saved


def keeping() -> bool:
    """Whether `builds_kept()` is active."""
    return _KEPT is not None


def kept(project: Any, key: tuple[Any, ...], make: Callable[[], T]) -> T:
    """`make()`, or, within `builds_kept()`, what it made for `project` and `key` already."""
    if _KEPT is None:
        return make()
    hit = _KEPT.get((id(project), *key))
    if hit is None or hit[0] is not project:
        hit = _KEPT[(id(project), *key)] = (project, make())
    return hit[1]


def built_blocks(project: Any, builder: str, module: str = "hmi.export.build"
                 ) -> list[tuple[tuple[Any, ...], Any]]:
    """Each call of `module`'s `builder` (e.g. hmi.export.build's "build_monitor") when the
    project is exported: its arguments and the Block it built (the export's own wiring and
    objects)."""
    return kept(project, ("built", builder, module),
                lambda: _spied_build(project, builder, module))


def _spied_build(project: Any, builder: str, module: str
                 ) -> list[tuple[tuple[Any, ...], Any]]:
    b = importlib.import_module(module)
    seen: list[tuple[tuple[Any, ...], Any]] = []
    real = getattr(b, builder)

    def spy(*args: Any, **kwargs: Any) -> Any:
        block = real(*args, **kwargs)
        seen.append((args, block))
        return block

    setattr(b, builder, spy)
    try:
        importlib.import_module("hmi.export.build").build(project)
    finally:
        setattr(b, builder, real)
    return seen


@dataclass
class Proof:
    name: str
    proved: bool
    detail: str
    loop_checks: int = 0
    obligations: int = 0


def index_lists(decl: Declared) -> tuple[str, ...]:
    """The INT arrays the block keeps between calls (the filter's Idx and Comb)."""
    return tuple(name for name in decl.order
                 if decl.sections[name] == "local" and decl.types[name].low is not None
                 and decl.types[name].name in INTS)


def indices_not_negative(decl: Declared, state: dict[str, Any]) -> Any:
    """Every INT array the block keeps between calls holds no negative value: the filter's
    index lists (Idx, Comb) start at 0 on a PLC, and the block writes indices and counts into
    them (that a call keeps it is proved with the rest)."""
    return z3.And(True, *[x >= 0 for name in index_lists(decl) for x in state[name]])


def indices_at_start(decl: Declared, state: dict[str, Any]) -> Any:
    """The index lists as a PLC starts them: every element 0."""
    return z3.And(True, *[x == 0 for name in index_lists(decl) for x in state[name]])


def _popcount(v: Any, n: int) -> Any:
    return z3.Sum([z3.ZeroExt(8, z3.Extract(k, k, v)) for k in range(n)])


def prove_filter(project: Any, text: str, max_distance: int,
                 tamper: Callable[[str], str] | None = None,
                 loop_limit: int = LOOP_LIMIT, split: tuple[str, ...] = ("FREE",),
                 invariant: Callable[[Declared, dict[str, Any]], Any] | None = None,
                 unchecked: int = UNCHECKED, at_once: bool = False,
                 stale: bool = False,
                 start: Callable[[Declared, dict[str, Any]], Any] | None = None
                 ) -> list[Proof]:
    """The exported filter FB of `project` (in the exported `text`, `tamper`ed if given)
    against the engine's filter: a list of proved (or refuted) properties; `at_once`: all
    proved, or the first property refuted, named by the counterexample that refutes it (what
    the mutation study asks; not every other property checked on its own as well).
    `stale`: a WHILE's pass that branches on an index list's element as the call found it
    is run once in each world to the loop's end (Symbolic's `stale`; what a mutant reading
    a Comb element left from an earlier call needs to stay concrete). `start`: a predicate
    over the state that only narrows the calls looked at (e.g. the index lists as a PLC
    starts them): a property it refutes is refuted, one it proves is not proved.

    With an `invariant` (a predicate over the block's variables that its initial values
    satisfy), the properties are proved for every state satisfying it, and one more
    property says a call keeps it: together, for every state a PLC reaches."""
    fb_name, wiring = filter_wiring(project)
    fb_text = pou_text(text, fb_name)
    fb = parse_fb(fb_text) if tamper is None else parse_changed(fb_text, tamper(fb_text))
    decl = declarations(fb)
    initial = Symbolic(fb).initial
    kept = tuple(f(decl, initial) for f in (invariant, start) if f is not None)
    cases = execute_cases(fb, frozenset(split), loop_limit, kept, unchecked,
                          frozenset(index_lists(decl) if stale else ()))
    sym = cases[0].sym
    init = sym.initial
    outputs = [v.name for v in project.outputs]
    n = len(outputs)
    index = {name: k for k, name in enumerate(outputs)}
    width = init[wiring.ports["Violations"]].size()
    wword = next(sym.decl.types[wiring.outputs[o]] for o in outputs)  # (BOOL outputs)
    assert wword.name == "BOOL"

    def read(name: str, depth: int) -> Any:
        return init[wiring.inputs[(name, depth)]]

    def bit(k: int, w: int = n) -> Any:
        return z3.BitVecVal(1 << k, w)

    policy = init[wiring.ports["Policy"]]
    reset = init[wiring.ports["Reset"]]
    ftc = init[wiring.ports["Ftc"]]
    latched0 = init[wiring.ports["Latched"]]
    fov = z3.Concat(*[z3.If(init[wiring.ports[f"FOV_{o}"]], z3.BitVecVal(1, 1),
                            z3.BitVecVal(0, 1)) for o in reversed(outputs)]) if n > 1 else \
        z3.If(init[wiring.ports[f"FOV_{outputs[0]}"]], z3.BitVecVal(1, 1), z3.BitVecVal(0, 1))
    # the constraints: output literals (depth 0, an output) and their context (the rest)
    cons = []
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
                value = read(lit.name, lit.depth)
                context.append(value if lit.positive else z3.Not(value))
        cons.append((z3.And(*context) if context else z3.BoolVal(True), pos, neg,
                     c.kind == "simple"))

    def violated(v: Any, j: int) -> Any:
        ctx, pos, neg, _ = cons[j]
        return z3.And(ctx, v & pos == pos, v & neg == 0)

    # masks: an actuator partition the diagnosers distrust, in FTC mode
    from hmi.project.diagnosers import diagnosers_of
    mask = z3.BitVecVal(0, n)
    for d in diagnosers_of(project):
        for p in d.partitions:
            if p.actuators:
                bits = sum(1 << index[o] for o in p.actuators)
                mask = z3.If(z3.And(ftc, read(p.flag, 0)), mask | bits, mask)
    monitor, block = policy == 0, policy == 1
    cand = z3.If(monitor, fov, fov & ~mask)
    word = z3.BitVecVal(0, width)
    for j in range(len(cons)):
        word = z3.If(violated(cand, j), word | bit(j, width), word)
    any_violation = word != 0
    safe = z3.BitVecVal(sum(1 << k for k, v in enumerate(project.outputs) if v.safe), n)
    # the correct policy
    f0 = f1 = z3.BitVecVal(0, n)
    for ctx, pos, neg, simple in cons:
        if simple:
            f0 = z3.If(ctx, f0 | pos, f0)
            f1 = z3.If(ctx, f1 | neg, f1)
    conflict = f0 & f1 != 0
    mem = (cand & ~f0) | f1
    unforced = ~(f0 | f1)

    def admissible(w: Any) -> Any:
        """w keeps the forced outputs, is within MAX_DISTANCE, violates no active combined
        constraint (the simple ones hold by the forcing)."""
        return z3.And((w ^ mem) & ~unforced == 0,
                      _popcount(w ^ mem, n) <= max_distance,
                      *[z3.Not(violated(w, j)) for j, (_, _, _, s) in enumerate(cons) if not s])

    def better(w: Any, x: Any) -> Any:
        """w before x in the exact strategy's order: distance, outputs switched on, then the
        lowest output where they differ is spared by w."""
        dw, dx = _popcount(w ^ mem, n), _popcount(x ^ mem, n)
        ow, ox = _popcount(w & ~mem, n), _popcount(x & ~mem, n)
        diff = (w ^ mem) ^ (x ^ mem)
        lowest = diff & -diff
        return z3.Or(dw < dx, z3.And(dw == dx, ow < ox),
                     z3.And(dw == dx, ow == ox, diff != 0, (x ^ mem) & lowest != 0))

    def vector(values: dict[str, Any]) -> Any:
        return z3.Concat(*[z3.If(values[wiring.outputs[o]], z3.BitVecVal(1, 1),
                                 z3.BitVecVal(0, 1)) for o in reversed(outputs)]) if n > 1 \
            else z3.If(values[wiring.outputs[outputs[0]]], z3.BitVecVal(1, 1),
                       z3.BitVecVal(0, 1))

    before = vector(init)
    correcting = z3.And(z3.Not(monitor), z3.Not(block), any_violation)
    all_vectors = [z3.BitVecVal(v, n) for v in range(1 << n)]
    none_admissible = z3.And(*[z3.Not(admissible(v)) for v in all_vectors])
    # (the corrector's vector, before the mask and the latch, as the spec's x)
    x = z3.BitVec("x", n)
    chosen = z3.And(admissible(x), *[z3.Not(z3.And(admissible(v), better(v, x)))
                                     for v in all_vectors])
    expected_fallback = z3.And(correcting, z3.Or(conflict, none_admissible))
    expected_latch = z3.Or(latched0, z3.And(block, any_violation))

    def final(v: Any) -> Any:
        v = z3.If(monitor, v, v & ~mask)
        return z3.If(expected_latch, safe, v)

    def properties(out: dict[str, Any]) -> dict[str, Any]:
        written = vector(out)
        latched = out[wiring.ports["Latched"]]
        fallback = out[wiring.ports["Fallback"]]
        return {
            "a fault reset releases the latch and changes no output": z3.Implies(
                reset, z3.And(z3.Not(latched), written == before)),
            "the violation word is the constraints violated by the candidate": z3.Implies(
                z3.Not(reset), out[wiring.ports["Violations"]] == word),
            "the block latch is set by a violation and kept": z3.Implies(
                z3.Not(reset), latched == expected_latch),
            "the fallback: F0/F1 conflict or no safe vector within MAX_DISTANCE": z3.Implies(
                z3.Not(reset), fallback == expected_fallback),
            "monitor, block and a clean candidate: the candidate, masked, the latch safe":
                z3.Implies(z3.And(z3.Not(reset), z3.Not(correcting)),
                           written == final(cand)),
            "correct: the exact strategy's unique vector, masked, or the safe state":
                z3.Implies(z3.And(z3.Not(reset), correcting, z3.Not(expected_fallback),
                                  chosen), written == final(x)),
            "correct without a safe vector: the safe state": z3.Implies(
                z3.And(z3.Not(reset), expected_fallback), written == z3.If(
                    expected_latch, safe, safe & ~z3.If(monitor, z3.BitVecVal(0, n), mask))),
        }

    per_case = [(case, properties(case.out)) for case in cases]
    if invariant is not None:
        for case, props in per_case:
            props["a call keeps the state invariant"] = invariant(decl, case.out)
    together = _all_valid(per_case, at_once)
    if together is None:
        together = [_valid_cases(name, [(case, props[name]) for case, props in per_case])
                    for name in per_case[0][1]]
        together.append(in_bounds(cases))
    if start is None:
        return together
    return [replace(p, proved=False, detail=f"not refuted from the start given ({p.detail}): "
                                            "not a proof") if p.proved else p
            for p in together]


IN_BOUNDS = "every array index is in bounds"  # (the property every proof ends with)


def _bounds(case: Case) -> Any:
    return z3.And(True, *[ob for ob, _ in case.sym.obligations])


def _all_valid(per_case: list[tuple[Case, dict[str, Any]]], at_once: bool = False
               ) -> list[Proof] | None:
    """Every property and the bounds proved by one z3 check per case (their conjunction:
    the terms of the block's outputs, which they share, are then bit-blasted once), or None
    when some case's check is not unsat: the properties are then checked one by one, each
    refuted with its own counterexample. `at_once`: instead, that case's counterexample
    refutes the first property it makes false (no further check)."""
    for case, props in per_case:
        named = {**props, IN_BOUNDS: _bounds(case)}
        found, solver = _decided(z3.Not(z3.Implies(z3.And(*case.assume),
                                                   z3.And(*named.values()))))
        if found == z3.unsat:
            continue
        if not at_once:
            return None
        if found != z3.sat:
            return [Proof("every property", False, f"z3: {solver.reason_unknown()}",
                          case.sym.checks)]
        model = solver.model()
        name = next((n for n, p in named.items()
                     if z3.is_false(model.eval(p, model_completion=True))), "every property")
        return [Proof(name, False, f"counterexample: {_shown(model)}", case.sym.checks)]
    checks = sum(case.sym.checks for case, _ in per_case)
    obligations = sum(len(case.sym.obligations) for case, _ in per_case)
    detail = f"proved in {len(per_case)} case(s)"
    return [Proof(name, True, detail, checks, obligations)
            for name in [*per_case[0][1], IN_BOUNDS]]


def in_bounds(cases: list[Case]) -> Proof:
    """Every array index in bounds on every path some input and state take (a constant index
    out of bounds ends its path: an obligation that the path is infeasible)."""
    return _valid_cases(IN_BOUNDS, [(case, _bounds(case)) for case in cases])


def _valid_cases(name: str, cases: list[tuple[Case, Any]]) -> Proof:
    """`name` proved when it holds in every case (each under its assumptions)."""
    checks = sum(case.sym.checks for case, _ in cases)
    obligations = sum(len(case.sym.obligations) for case, _ in cases)
    for case, prop in cases:
        proof = _valid(name, z3.Implies(z3.And(*case.assume), prop), case.sym)
        if not proof.proved:
            return proof
    return Proof(name, True, f"proved in {len(cases)} case(s)", checks, obligations)


def _valid(name: str, prop: Any, sym: Symbolic,
           shown_if: Callable[[str], bool] | None = None) -> Proof:
    """`prop` proved valid, or refuted with a counterexample (the values of the constants
    `shown_if` accepts: all but the executor's own, when None)."""
    found, solver = _decided(z3.Not(prop))
    if found == z3.unsat:
        return Proof(name, True, "proved", sym.checks, len(sym.obligations))
    if found == z3.sat:
        return Proof(name, False, f"counterexample: {_shown(solver.model(), shown_if)}",
                     sym.checks)
    return Proof(name, False, f"z3: {solver.reason_unknown()}", sym.checks)


# The work (z3's own count, the same on every machine and run) a bit-blasted check may take
# before z3's default solver is asked instead: about 10 s of CPU here. Bit-blasting decides
# the unsat questions of an equivalence in well under a second, but some sat ones (a mutant
# that reads integers no case fixes) not in minutes, which the default solver answers.
BLASTED_RLIMIT = 20_000_000


def _decided(formula: Any) -> tuple[Any, Any]:
    """z3's answer on `formula` (sat, unsat or unknown) and the solver that gave it: first
    with the words bit-blasted before the search (what the properties of a block are made
    of; its few integers stay integers: every step keeps satisfiability, so unsat and a
    model mean what they say), then, past BLASTED_RLIMIT, with z3's default solver.
    Measured on the palletizer filter's cases: 1.5-5 s each by the default solver, 0.1-0.8 s
    bit-blasted."""
    solver = z3.Then("simplify", "propagate-values", "solve-eqs", "simplify", "bit-blast",
                     "smt").solver()
    solver.set("rlimit", BLASTED_RLIMIT)
    solver.add(formula)
    found = solver.check()
    if found != z3.unknown:
        return found, solver
    solver = z3.Solver()
    solver.add(formula)
    return solver.check(), solver


def _shown(model: Any, shown_if: Callable[[str], bool] | None = None) -> str:
    """A counterexample's values: of the constants `shown_if` accepts (all but the
    executor's own, when None), by name, cut at 600 characters."""
    return ", ".join(f"{d.name()} = {model[d]}" for d in sorted(
        model.decls(), key=lambda d: d.name()) if not d.name().startswith("$")
        and d.arity() == 0 and (shown_if is None or shown_if(d.name())))[:600]
