"""The Boolean expression language of project files.

Expressions are read by the standard library's parser (``ast``) and then checked node by
node against a whitelist; nothing is ever evaluated by Python. The accepted language:

* names of variables (inputs, outputs, memories, timers, observers, steps ``X1``, flags);
* ``and``, ``or``, ``not``, parentheses, ``True``/``False`` (or ``1``/``0``);
* ``prev(x)`` — x at the previous scan (the papers' x*), ``prev(x, n)`` — n scans ago;
* ``rise(x)`` = ``x and not prev(x)``, ``fall(x)`` = ``prev(x) and not x``;
* ``X3.t`` — how long step X3 has been active, compared with a duration: ``X3.t >= 2s``.

Parsed expressions are small immutable trees; :func:`compile_bool` turns one into a closure
over the engine's value image, and :func:`monomial_literals` reads a safety constraint as
the product of literals the filter works on.
"""

from __future__ import annotations

import ast
import difflib
import re
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from hmi.errors import SourcePos
from hmi.limits import MAX_EXPR_CHARS, MAX_EXPR_DEPTH
from hmi.logic.names import describe_non_ascii, first_non_ascii
from hmi.timefmt import DURATION_HINT, DurationError, parse_duration

MAX_PREV_DEPTH = 64

# --------------------------------------------------------------------------------------------
# Tree
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Node:
    col: int  # offset of the node in the source text (0-based), for error positions


@dataclass(frozen=True)
class Const(Node):
    value: bool


@dataclass(frozen=True)
class Var(Node):
    name: str
    depth: int = 0  # 0: value at this scan; n: value n scans ago (prev(x, n))


@dataclass(frozen=True)
class Not(Node):
    operand: Node


@dataclass(frozen=True)
class And(Node):
    operands: tuple[Node, ...]


@dataclass(frozen=True)
class Or(Node):
    operands: tuple[Node, ...]


@dataclass(frozen=True)
class StepTime(Node):
    """How long a step has been active, in microseconds (numeric)."""

    step: str


@dataclass(frozen=True)
class Duration(Node):
    us: int


@dataclass(frozen=True)
class Compare(Node):
    left: Node
    op: str  # one of < <= > >= == !=
    right: Node


NUMERIC = (StepTime, Duration)


@dataclass(frozen=True)
class Expr:
    """A parsed expression with the text it came from and where that text is."""

    source: str
    root: Node
    pos: SourcePos

    def pos_of(self, node: Node) -> SourcePos:
        return self.pos.shifted(node.col)

    def __str__(self) -> str:
        return self.source


class ExprError(Exception):
    """A syntax or name error inside an expression, at a column of its text."""

    def __init__(self, pos: SourcePos, message: str, expected: str | None = None):
        super().__init__(message)
        self.pos = pos
        self.message = message
        self.expected = expected


ALLOWED = ("names, and, or, not, parentheses, True/False, prev(x), prev(x, n), rise(x), "
           "fall(x), and step times such as X3.t >= 2s")

# --------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------

_DURATION_IN_EXPR = re.compile(r"(?<![\w.])([0-9]+(?:\.[0-9]+)?)[ \t]*(us|ms|s|min|m|h)\b")
# What nests in Python's parser: parentheses (calls included) and chains of `not`; `and` and
# `or` end a chain of `not`.
_NESTING = re.compile(r"[()]|\b(?:not|and|or)\b")


def _replace_durations(text: str, pos: SourcePos) -> tuple[str, list[int], dict[str, int]]:
    """Swap duration literals (not Python) for placeholder names; keep a column map back."""
    out: list[str] = []
    colmap: list[int] = []
    durations: dict[str, int] = {}
    last = 0
    for match in _DURATION_IN_EXPR.finditer(text):
        out.append(text[last:match.start()])
        colmap.extend(range(last, match.start()))
        name = f"__duration_{len(durations)}"
        try:
            durations[name] = parse_duration(match.group(1) + match.group(2))
        except DurationError as exc:
            raise ExprError(pos.shifted(match.start()), f"the time {match.group()!r} "
                            f"{exc.reason}", DURATION_HINT) from None
        out.append(name)
        colmap.extend([match.start()] * len(name))
        last = match.end()
    out.append(text[last:])
    colmap.extend(range(last, len(text) + 1))
    return "".join(out), colmap, durations


def expression_text(text: str) -> str:
    """The text an expression is parsed from (its columns count in it): an expression
    written over several lines is read as one, each run of blanks a single space."""
    return " ".join(text.split()) if "\n" in text.strip() else text


def parse_expr(text: str, pos: SourcePos) -> Expr:
    """Parse `text` (located at `pos`) into an :class:`Expr`, or raise ExprError."""
    if not text.strip():
        raise ExprError(pos, "empty expression", ALLOWED)
    text = expression_text(text)
    _check_text(text, pos)
    source, colmap, durations = _replace_durations(text, pos)

    def at(col: int) -> SourcePos:
        col = max(0, min(col, len(colmap) - 1))
        return pos.shifted(colmap[col])

    try:
        tree = ast.parse(source, mode="eval")
    except SyntaxError as exc:
        col = (exc.offset or 1) - 1
        raise ExprError(at(col), f"syntax error in expression {_short(text)!r}: {exc.msg}",
                        ALLOWED) from None
    except (RecursionError, MemoryError, ValueError) as exc:  # bounded above; never a crash
        raise ExprError(pos, f"expression too complex for the parser ({type(exc).__name__})",
                        f"a simpler expression (at most {MAX_EXPR_DEPTH} levels of nesting)"
                        ) from None
    builder = _Builder(at, durations, colmap)
    root = builder.build(tree.body)
    if isinstance(root, NUMERIC):
        raise ExprError(at(0), "a time value alone is not a condition",
                        "a comparison such as X3.t >= 2s")
    return Expr(text, root, pos)


def _check_text(text: str, pos: SourcePos) -> None:
    """Refuse, before Python's parser sees it, what it would misread or choke on: non-ASCII
    characters (NFKC would fold a look-alike into another name), and an expression too long
    or nested too deep (the parser recurses per level: a thousand `not` exhaust its stack).
    """
    if len(text) > MAX_EXPR_CHARS:
        raise ExprError(pos, f"the expression is {len(text):,} characters long",
                        f"at most {MAX_EXPR_CHARS:,} characters (a limit of plchmi; split it "
                        "with observers)")
    odd = first_non_ascii(text)
    if odd is not None:
        raise ExprError(pos.shifted(odd), f"{describe_non_ascii(text[odd])} is not allowed in "
                        "an expression", "names of ASCII letters, digits and _")
    depth = 0
    chains = [0]  # per open parenthesis: the `not` chain running in it
    for match in _NESTING.finditer(text):
        token = match.group()
        if token == "(":
            chains.append(0)
        elif token == ")":
            if len(chains) > 1:
                chains.pop()
        elif token == "not":
            chains[-1] += 1
        else:
            chains[-1] = 0
        level = len(chains) - 1 + sum(chains)
        if level > depth:
            depth = level
            if depth > MAX_EXPR_DEPTH:
                raise ExprError(pos.shifted(match.start()), "the expression is nested more "
                                f"than {MAX_EXPR_DEPTH} deep (parentheses and not inside each "
                                "other)", f"at most {MAX_EXPR_DEPTH} levels (a limit of plchmi)")


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:77] + "..."


class _Builder:
    def __init__(self, at: Callable[[int], SourcePos], durations: Mapping[str, int],
                 colmap: list[int]):
        self.at = at
        self.durations = durations
        self.colmap = colmap

    def col(self, node: ast.AST) -> int:
        offset = getattr(node, "col_offset", 0)
        return self.colmap[min(offset, len(self.colmap) - 1)]

    def fail(self, node: ast.AST, message: str, expected: str | None = ALLOWED) -> ExprError:
        return ExprError(self.at(getattr(node, "col_offset", 0)), message, expected)

    def build(self, node: ast.AST) -> Node:
        col = self.col(node)
        if isinstance(node, ast.BoolOp):
            operands = tuple(self.boolean(v) for v in node.values)
            kind = And if isinstance(node.op, ast.And) else Or
            flat: list[Node] = []
            for operand in operands:  # a and (b and c) is one product: keep it flat
                flat.extend(operand.operands if isinstance(operand, kind) else (operand,))
            return kind(col, tuple(flat))
        if isinstance(node, ast.UnaryOp):
            if isinstance(node.op, ast.Not):
                return Not(col, self.boolean(node.operand))
            raise self.fail(node, f"operator {_op_text(node.op)!r} is not allowed",
                            "not, and, or")
        if isinstance(node, ast.Name):
            if node.id in self.durations:
                return Duration(col, self.durations[node.id])
            if node.id in ("prev", "rise", "fall"):
                raise self.fail(node, f"{node.id} is a function", f"{node.id}(x)")
            return Var(col, node.id)
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool):
                return Const(col, node.value)
            if isinstance(node.value, int) and node.value in (0, 1):
                return Const(col, bool(node.value))
            raise self.fail(node, f"the constant {node.value!r} is not allowed here",
                            "True, False, 1, 0 or a duration such as 2s")
        if isinstance(node, ast.Call):
            return self.call(node)
        if isinstance(node, ast.Attribute):
            if isinstance(node.value, ast.Name) and node.attr == "t":
                return StepTime(col, node.value.id)
            raise self.fail(node, f"attribute .{node.attr} is not allowed",
                            "a step's time, such as X3.t")
        if isinstance(node, ast.Compare):
            return self.compare(node)
        if isinstance(node, ast.BinOp):
            raise self.fail(node, f"arithmetic operator {_op_text(node.op)!r} is not allowed "
                            "(use and / or / not)", ALLOWED)
        raise self.fail(node, f"{_describe_ast(node)} is not allowed in an expression")

    def boolean(self, node: ast.AST) -> Node:
        built = self.build(node)
        if isinstance(built, NUMERIC):
            raise self.fail(node, "a time value is used where a condition is expected",
                            "a comparison such as X3.t >= 2s")
        return built

    def call(self, node: ast.Call) -> Node:
        col = self.col(node)
        if not isinstance(node.func, ast.Name) or node.func.id not in ("prev", "rise", "fall"):
            name = node.func.id if isinstance(node.func, ast.Name) else "this"
            raise self.fail(node, f"function {name!r} is not allowed",
                            "prev(x), prev(x, n), rise(x) or fall(x)")
        fname = node.func.id
        if node.keywords:
            raise self.fail(node, f"{fname}() takes no keyword arguments")
        nargs = len(node.args)
        if (fname == "prev" and nargs not in (1, 2)) or (fname != "prev" and nargs != 1):
            usage = "prev(x) or prev(x, n)" if fname == "prev" else f"{fname}(x)"
            raise self.fail(node, f"{fname}() given {nargs} arguments", usage)
        target = node.args[0]
        if not isinstance(target, ast.Name) or target.id in self.durations:
            raise self.fail(target, f"{fname}() applies to a variable name",
                            f"{fname}(x) with x a variable")
        depth = 1
        if nargs == 2:
            arg = node.args[1]
            if (not isinstance(arg, ast.Constant) or isinstance(arg.value, bool)
                    or not isinstance(arg.value, int)):
                raise self.fail(arg, "the depth of prev() must be a whole number of scans",
                                f"an integer from 1 to {MAX_PREV_DEPTH}")
            depth = arg.value
            if not 1 <= depth <= MAX_PREV_DEPTH:
                raise self.fail(arg, f"prev() depth {depth} is out of range",
                                f"an integer from 1 to {MAX_PREV_DEPTH}")
        name = target.id
        tcol = self.col(target)
        if fname == "prev":
            return Var(col, name, depth)
        now, before = Var(tcol, name, 0), Var(tcol, name, 1)
        if fname == "rise":
            return And(col, (now, Not(col, before)))
        return And(col, (before, Not(col, now)))

    def compare(self, node: ast.Compare) -> Node:
        if len(node.ops) != 1:
            raise self.fail(node, "chained comparisons are not allowed",
                            "one comparison such as X3.t >= 2s")
        left = self.build(node.left)
        right = self.build(node.comparators[0])
        for side, src in ((left, node.left), (right, node.comparators[0])):
            if not isinstance(side, NUMERIC):
                raise self.fail(src, "only times can be compared",
                                "a comparison such as X3.t >= 2s")
        op = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==",
              ast.NotEq: "!="}.get(type(node.ops[0]))
        if op is None:
            raise self.fail(node, f"comparison {_op_text(node.ops[0])!r} is not allowed",
                            "<, <=, >, >=, ==, !=")
        return Compare(self.col(node), left, op, right)


def _op_text(op: ast.AST) -> str:
    return {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.BitAnd: "&",
            ast.BitOr: "|", ast.BitXor: "^", ast.Invert: "~", ast.USub: "-", ast.UAdd: "+",
            ast.Mod: "%", ast.Pow: "**", ast.In: "in", ast.Is: "is", ast.NotIn: "not in",
            ast.IsNot: "is not", ast.FloorDiv: "//", ast.LShift: "<<", ast.RShift: ">>",
            }.get(type(op), type(op).__name__)


def _describe_ast(node: ast.AST) -> str:
    names = {ast.Subscript: "indexing", ast.Lambda: "lambda", ast.IfExp: "if/else",
             ast.List: "a list", ast.Tuple: "a tuple", ast.Dict: "a dict",
             ast.JoinedStr: "an f-string", ast.NamedExpr: "':='", ast.Set: "a set"}
    return names.get(type(node), type(node).__name__)


# --------------------------------------------------------------------------------------------
# Walking and checking
# --------------------------------------------------------------------------------------------


def walk(node: Node) -> Iterator[Node]:
    """Every node of the tree, parents first."""
    yield node
    if isinstance(node, Not):
        yield from walk(node.operand)
    elif isinstance(node, (And, Or)):
        for operand in node.operands:
            yield from walk(operand)
    elif isinstance(node, Compare):
        yield from walk(node.left)
        yield from walk(node.right)


def variables(expr: Expr) -> list[Var]:
    return [n for n in walk(expr.root) if isinstance(n, Var)]


def max_depth(expr: Expr) -> int:
    return max((v.depth for v in variables(expr)), default=0)


def check_names(expr: Expr, namespace: Mapping[str, str], steps: Collection[str] = (),
                allowed_kinds: set[str] | None = None, context: str = "") -> list[ExprError]:
    """Name errors in `expr`: unknown names, step times of non-steps, forbidden kinds."""
    problems: list[ExprError] = []
    for node in walk(expr.root):
        if isinstance(node, Var):
            kind = namespace.get(node.name)
            if kind is None:
                problems.append(ExprError(expr.pos_of(node), f"unknown name {node.name!r}",
                                          _suggest(node.name, namespace)))
            elif allowed_kinds is not None and kind not in allowed_kinds:
                problems.append(ExprError(
                    expr.pos_of(node), f"{node.name!r} is a {kind} and cannot be used "
                    f"{context or 'here'}", "one of: " + ", ".join(sorted(allowed_kinds))))
        elif isinstance(node, StepTime) and node.step not in steps:
            problems.append(ExprError(expr.pos_of(node),
                                      f"{node.step}.t: {node.step!r} is not a GRAFCET step",
                                      _suggest(node.step, dict.fromkeys(steps, "step"))))
    return problems


SUGGEST_AMONG = 500  # difflib compares with every name: beyond this, a cheaper look-up


def _suggest(name: str, namespace: Mapping[str, str]) -> str:
    if len(namespace) > SUGGEST_AMONG:  # thousands of names, maybe thousands of typos
        folded = name.lower()
        close = [n for n in namespace if n.lower() == folded][:3]
    else:
        close = difflib.get_close_matches(name, list(namespace), n=3, cutoff=0.5)
    if close:
        return "a known name; did you mean " + " or ".join(repr(c) for c in close) + "?"
    if not namespace:
        return "a declared name"
    known = sorted(namespace)
    shown = ", ".join(known[:12]) + (", ..." if len(known) > 12 else "")
    return "one of " + shown


# --------------------------------------------------------------------------------------------
# Monomials (safety constraints)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Literal:
    """One factor of a monomial: a variable (possibly from an earlier scan) or its negation."""

    name: str
    depth: int
    positive: bool

    def __str__(self) -> str:
        text = self.name if self.depth == 0 else (
            f"prev({self.name})" if self.depth == 1 else f"prev({self.name}, {self.depth})")
        return text if self.positive else f"not {text}"


class NotMonomial(Exception):
    def __init__(self, node: Node, reason: str):
        super().__init__(reason)
        self.node = node
        self.reason = reason


def monomial_literals(expr: Expr) -> tuple[Literal, ...] | None:
    """The literals of a product (AND of possibly negated variables).

    Returns None for a product that can never be true (it holds x and not x, or False).
    Raises NotMonomial, pointing at the offending node, for anything else (or, a
    comparison, a negated product).
    """
    literals: list[Literal] = []
    never = False

    def visit(node: Node, positive: bool) -> None:
        nonlocal never
        if isinstance(node, Var):
            literals.append(Literal(node.name, node.depth, positive))
        elif isinstance(node, Not):
            if not isinstance(node.operand, (Var, Not, Const)):
                raise NotMonomial(node, "a negated group is not a product of literals "
                                  "(write each literal negated, or split the constraint)")
            visit(node.operand, not positive)
        elif isinstance(node, And):
            if not positive:
                raise NotMonomial(node, "a negated product is a sum, not a monomial")
            for operand in node.operands:
                visit(operand, True)
        elif isinstance(node, Const):
            if node.value != positive:
                never = True
        elif isinstance(node, Or):
            raise NotMonomial(node, "'or' makes a sum of products; a safety constraint must "
                              "be one product (split it into several constraints)")
        else:
            raise NotMonomial(node, "a comparison is not a literal; define a timer or an "
                              "observer for it and use its name")

    visit(expr.root, True)
    unique: dict[tuple[str, int], Literal] = {}
    for lit in literals:
        key = (lit.name, lit.depth)
        seen = unique.get(key)
        if seen is not None and seen.positive != lit.positive:
            never = True
        unique.setdefault(key, lit)
    if never:
        return None
    return tuple(unique.values())


# --------------------------------------------------------------------------------------------
# Compilation
# --------------------------------------------------------------------------------------------

# Current values indexed by slot: bools (inputs, outputs, memories, timers, observers,
# steps, flags) and ints (step activity times); hmi.engine.layout says which slot is which.
Image = list[Any]
# history[0] is the image one scan ago (the engine keeps past images as tuples: never changed)
History = Sequence[Sequence[Any]]
BoolFn = Callable[[Image, History], bool]
NumFn = Callable[[Image, History], int]


def compile_bool(expr: Expr | Node, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int] | None = None) -> BoolFn:
    """A closure computing the expression on an image and its history; never eval."""
    root = expr.root if isinstance(expr, Expr) else expr
    return _compile(root, slots, step_time_slots or {})


def _compile(node: Node, slots: Mapping[str, int], times: Mapping[str, int]) -> BoolFn:
    if isinstance(node, Const):
        value = node.value
        return lambda v, h: value
    if isinstance(node, Var):
        slot = slots[node.name]
        if node.depth == 0:
            return lambda v, h: v[slot]
        back = node.depth - 1
        return lambda v, h: h[back][slot]
    if isinstance(node, Not):
        inner = _compile(node.operand, slots, times)
        return lambda v, h: not inner(v, h)
    if isinstance(node, (And, Or)):
        parts = [_compile(op, slots, times) for op in node.operands]
        if isinstance(node, And) and all(_is_literal(op) for op in node.operands):
            return _literal_product(node.operands, slots)
        if len(parts) == 2:
            a, b = parts
            if isinstance(node, And):
                return lambda v, h: a(v, h) and b(v, h)
            return lambda v, h: a(v, h) or b(v, h)
        if isinstance(node, And):
            def all_of(v: Image, h: History, parts: tuple[BoolFn, ...] = tuple(parts)
                       ) -> bool:
                for part in parts:
                    if not part(v, h):
                        return False
                return True
            return all_of

        def any_of(v: Image, h: History, parts: tuple[BoolFn, ...] = tuple(parts)) -> bool:
            for part in parts:
                if part(v, h):
                    return True
            return False
        return any_of
    if isinstance(node, Compare):
        left = _compile_num(node.left, times)
        right = _compile_num(node.right, times)
        op = node.op
        if op == ">=":
            return lambda v, h: left(v, h) >= right(v, h)
        if op == ">":
            return lambda v, h: left(v, h) > right(v, h)
        if op == "<=":
            return lambda v, h: left(v, h) <= right(v, h)
        if op == "<":
            return lambda v, h: left(v, h) < right(v, h)
        if op == "==":
            return lambda v, h: left(v, h) == right(v, h)
        return lambda v, h: left(v, h) != right(v, h)
    raise TypeError(f"not a Boolean node: {node!r}")


def _compile_num(node: Node, times: Mapping[str, int]) -> NumFn:
    if isinstance(node, Duration):
        us = node.us
        return lambda v, h: us
    if isinstance(node, StepTime):
        slot = times[node.step]
        return lambda v, h: v[slot]
    raise TypeError(f"not a numeric node: {node!r}")


def _is_literal(node: Node) -> bool:
    return isinstance(node, Var) or (isinstance(node, Not) and isinstance(node.operand, Var))


def _literal_product(operands: Sequence[Node], slots: Mapping[str, int]) -> BoolFn:
    """A product of literals as index tuples: the common shape of constraints."""
    now_pos: list[int] = []
    now_neg: list[int] = []
    old_pos: list[tuple[int, int]] = []
    old_neg: list[tuple[int, int]] = []
    for op in operands:
        positive = isinstance(op, Var)
        var = op.operand if isinstance(op, Not) else op
        assert isinstance(var, Var)
        slot = slots[var.name]
        if var.depth == 0:
            (now_pos if positive else now_neg).append(slot)
        else:
            (old_pos if positive else old_neg).append((var.depth - 1, slot))
    np_, nn_, op_, on_ = tuple(now_pos), tuple(now_neg), tuple(old_pos), tuple(old_neg)

    def product(v: Image, h: History) -> bool:
        for i in np_:
            if not v[i]:
                return False
        for i in nn_:
            if v[i]:
                return False
        for d, i in op_:
            if not h[d][i]:
                return False
        for d, i in on_:
            if h[d][i]:
                return False
        return True
    return product


def to_text(node: Node) -> str:
    """A canonical rendering of a (sub)expression, used in explanations."""
    if isinstance(node, Const):
        return "True" if node.value else "False"
    if isinstance(node, Var):
        if node.depth == 0:
            return node.name
        return f"prev({node.name})" if node.depth == 1 else f"prev({node.name}, {node.depth})"
    if isinstance(node, Not):
        inner = to_text(node.operand)
        return f"not {inner}" if isinstance(node.operand, (Var, Const)) else f"not ({inner})"
    if isinstance(node, (And, Or)):
        word = " and " if isinstance(node, And) else " or "
        parts = []
        for op in node.operands:
            text = to_text(op)
            parts.append(f"({text})" if isinstance(op, (And, Or)) else text)
        return word.join(parts)
    if isinstance(node, StepTime):
        return f"{node.step}.t"
    if isinstance(node, Duration):
        from hmi.timefmt import format_duration
        return format_duration(node.us)
    if isinstance(node, Compare):
        return f"{to_text(node.left)} {node.op} {to_text(node.right)}"
    raise TypeError(node)
