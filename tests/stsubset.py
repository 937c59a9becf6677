"""A small interpreter of the IEC 61131-3 Structured Text subset `plchmi export` emits.

A test oracle, deliberately independent of hmi/export: it reads the exported *text* (never
the PLC model it was written from), with its own lexer, parser, type checks and IEC standard
timers (TON, TOF as IEC 61131-3 defines them), and runs it scan by scan on an injected clock.
It lives in tests/ because it is a peer that checks the export, not part of the product: a
shared module would let a writer's misunderstanding pass in both.

The subset: FUNCTION_BLOCK and PROGRAM with VAR_INPUT/VAR_OUTPUT/VAR/VAR CONSTANT/
VAR_EXTERNAL; a CONFIGURATION with VAR_GLOBAL (AT addresses), one RESOURCE, TASKs and PROGRAM
instances; types BOOL, INT, DINT, TIME, WORD, DWORD, LWORD, one-dimensional ARRAYs, TON, TOF
and the file's FBs; statements :=, FB calls with named inputs, IF/ELSIF/ELSE, CASE, FOR (BY),
WHILE, EXIT, the empty statement; expressions OR XOR AND = <> < <= > >= + - * NOT, unary -,
SHL, member access, indexing, BOOL/integer/typed bit-string/TIME literals. Types are checked
when the file is loaded (a PLC compiler would refuse the same mistakes); integer overflow,
an index out of bounds and a WHILE that never ends raise at run time.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from operator import itemgetter

BITS = {"WORD": 16, "DWORD": 32, "LWORD": 64}
INTS = {"INT": (-(1 << 15), (1 << 15) - 1), "DINT": (-(1 << 31), (1 << 31) - 1)}
TIME_MAX_US = ((1 << 31) - 1) * 1000  # a 32-bit TIME in milliseconds
ANY_INT = "ANY_INT"  # an untyped integer literal
MAX_LOOPS = 1_000_000


class StError(Exception):
    """Syntax, type or run-time error in the ST text, with the line it happened at."""


# --------------------------------------------------------------------------------------------
# Lexer
# --------------------------------------------------------------------------------------------

TOKEN = re.compile(r"""
    (?P<ws>\s+) | (?P<comment>\(\*.*?\*\)) |
    (?P<time>(?:T|TIME)\#[0-9dhmsu_]+) |
    (?P<typed>(?:BOOL|INT|DINT|WORD|DWORD|LWORD)\#(?:16\#[0-9A-Fa-f_]+|2\#[01_]+|[0-9_]+)) |
    (?P<int>16\#[0-9A-Fa-f_]+|2\#[01_]+|[0-9]+) |
    (?P<ident>[A-Za-z_][A-Za-z0-9_]*) |
    (?P<addr>%[IQM][XWB]?[0-9]+(?:\.[0-9]+)?) |
    (?P<op>:=|<>|<=|>=|\.\.|[-+*<>=();:,\[\].])
""", re.VERBOSE | re.DOTALL | re.IGNORECASE)
KEYWORDS = {
    "FUNCTION_BLOCK", "END_FUNCTION_BLOCK", "PROGRAM", "END_PROGRAM", "VAR", "VAR_INPUT",
    "VAR_OUTPUT", "VAR_EXTERNAL", "VAR_GLOBAL", "END_VAR", "CONSTANT", "AT", "ARRAY", "OF",
    "IF", "THEN", "ELSIF", "ELSE", "END_IF", "CASE", "END_CASE", "FOR", "TO", "BY", "DO",
    "END_FOR", "WHILE", "END_WHILE", "EXIT", "AND", "OR", "XOR", "NOT", "TRUE", "FALSE",
    "CONFIGURATION", "END_CONFIGURATION", "RESOURCE", "END_RESOURCE", "ON", "TASK", "WITH",
}


@dataclass(frozen=True)
class Tok:
    kind: str  # kw, ident, int, typed, time, addr, op, eof
    text: str
    line: int


def tokenize(text: str) -> list[Tok]:
    out: list[Tok] = []
    pos, line = 0, 1
    while pos < len(text):
        match = TOKEN.match(text, pos)
        if match is None:
            raise StError(f"line {line}: unexpected character {text[pos]!r}")
        kind = match.lastgroup or ""
        value = match.group()
        if kind == "ident" and value.upper() in KEYWORDS:
            out.append(Tok("kw", value.upper(), line))
        elif kind not in ("ws", "comment"):
            out.append(Tok(kind, value, line))
        line += value.count("\n")
        pos = match.end()
    out.append(Tok("eof", "", line))
    return out


def parse_time(text: str) -> int:
    """`T#1d2h3m4s5ms` in microseconds."""
    body = text.split("#", 1)[1].replace("_", "").lower()
    us = 0
    for number, unit in re.findall(r"(\d+)(ms|us|d|h|m|s)", body):
        us += int(number) * {"d": 86_400_000_000, "h": 3_600_000_000, "m": 60_000_000,
                             "s": 1_000_000, "ms": 1000, "us": 1}[unit]
    if re.sub(r"\d+(ms|us|d|h|m|s)", "", body):
        raise StError(f"bad TIME literal {text}")
    return us


def parse_int(text: str) -> int:
    text = text.replace("_", "")
    if text.startswith("16#"):
        return int(text[3:], 16)
    if text.startswith("2#"):
        return int(text[2:], 2)
    return int(text)


# --------------------------------------------------------------------------------------------
# Syntax tree
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TypeRef:
    name: str  # upper case: BOOL, INT, ..., TON, an FB name
    array: tuple[int, int] | None = None


@dataclass
class VarDecl:
    name: str
    type: TypeRef
    section: str
    constant: bool
    init: object = None  # an expression node, a list of them, or None
    address: str | None = None
    line: int = 0


@dataclass
class Pou:
    name: str
    kind: str  # FUNCTION_BLOCK or PROGRAM
    decls: list[VarDecl]
    body: list
    line: int


@dataclass
class Config:
    globals: list[VarDecl]
    tasks: dict[str, tuple[int, int]]  # name -> (interval us, priority)
    instances: list[tuple[str, str, str]]  # (instance, task, program)


# Expressions and statements are tuples: (kind, line, ...)


class Parser:
    def __init__(self, text: str):
        self.toks = tokenize(text)
        self.i = 0

    # -- helpers -----------------------------------------------------------------------------
    @property
    def tok(self) -> Tok:
        return self.toks[self.i]

    def next(self) -> Tok:
        tok = self.toks[self.i]
        self.i += 1
        return tok

    def at(self, *texts: str) -> bool:
        return self.tok.kind in ("kw", "op") and self.tok.text in texts

    def expect(self, text: str) -> Tok:
        if not self.at(text):
            raise StError(f"line {self.tok.line}: expected {text!r}, found {self.tok.text!r}")
        return self.next()

    def ident(self) -> str:
        tok = self.next()
        if tok.kind != "ident":
            raise StError(f"line {tok.line}: expected a name, found {tok.text!r}")
        return tok.text.upper()

    # -- file --------------------------------------------------------------------------------
    def file(self) -> tuple[dict[str, Pou], Config | None]:
        pous: dict[str, Pou] = {}
        config = None
        while self.tok.kind != "eof":
            if self.at("FUNCTION_BLOCK", "PROGRAM"):
                pou = self.pou()
                if pou.name in pous:
                    raise StError(f"line {pou.line}: {pou.name} declared twice")
                pous[pou.name] = pou
            elif self.at("CONFIGURATION"):
                config = self.configuration()
            else:
                raise StError(f"line {self.tok.line}: unexpected {self.tok.text!r}")
        return pous, config

    def pou(self) -> Pou:
        start = self.next()
        kind = start.text
        name = self.ident()
        decls: list[VarDecl] = []
        while self.at("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_EXTERNAL"):
            decls += self.var_block()
        body = self.statements(f"END_{kind}")
        self.expect(f"END_{kind}")
        return Pou(name, kind, decls, body, start.line)

    def var_block(self) -> list[VarDecl]:
        section = self.next().text
        constant = False
        if self.at("CONSTANT"):
            self.next()
            constant = True
        decls = []
        while not self.at("END_VAR"):
            line = self.tok.line
            names = [self.ident()]
            while self.at(","):
                self.next()
                names.append(self.ident())
            address = None
            if self.at("AT"):
                self.next()
                tok = self.next()
                if tok.kind != "addr":
                    raise StError(f"line {tok.line}: expected an address after AT")
                address = tok.text.upper()
            self.expect(":")
            type_ = self.type_ref()
            init = None
            if self.at(":="):
                self.next()
                if self.at("["):
                    self.next()
                    init = [self.expr()]
                    while self.at(","):
                        self.next()
                        init.append(self.expr())
                    self.expect("]")
                else:
                    init = self.expr()
            self.expect(";")
            decls += [VarDecl(n, type_, section, constant, init, address, line) for n in names]
        self.expect("END_VAR")
        return decls

    def type_ref(self) -> TypeRef:
        if self.at("ARRAY"):
            self.next()
            self.expect("[")
            low = self.signed_int()
            self.expect("..")
            high = self.signed_int()
            self.expect("]")
            self.expect("OF")
            return TypeRef(self.ident(), (low, high))
        return TypeRef(self.ident())

    def signed_int(self) -> int:
        sign = 1
        if self.at("-"):
            self.next()
            sign = -1
        tok = self.next()
        if tok.kind != "int":
            raise StError(f"line {tok.line}: expected an integer")
        return sign * parse_int(tok.text)

    def configuration(self) -> Config:
        self.expect("CONFIGURATION")
        self.ident()
        globals_: list[VarDecl] = []
        tasks: dict[str, tuple[int, int]] = {}
        instances: list[tuple[str, str, str]] = []
        while self.at("VAR_GLOBAL"):
            globals_ += self.var_block()
        self.expect("RESOURCE")
        self.ident()
        self.expect("ON")
        self.ident()
        while self.at("VAR_GLOBAL"):
            globals_ += self.var_block()
        while not self.at("END_RESOURCE"):
            if self.at("TASK"):
                self.next()
                name = self.ident()
                self.expect("(")
                args: dict[str, Tok] = {}
                while not self.at(")"):
                    key = self.ident()
                    self.expect(":=")
                    args[key] = self.next()
                    if self.at(","):
                        self.next()
                self.expect(")")
                self.expect(";")
                tasks[name] = (parse_time(args["INTERVAL"].text),
                               parse_int(args["PRIORITY"].text))
            else:
                self.expect("PROGRAM")
                inst = self.ident()
                self.expect("WITH")
                task = self.ident()
                self.expect(":")
                instances.append((inst, task, self.ident()))
                self.expect(";")
        self.expect("END_RESOURCE")
        self.expect("END_CONFIGURATION")
        return Config(globals_, tasks, instances)

    # -- statements --------------------------------------------------------------------------
    def statements(self, *ends: str) -> list:
        out = []
        while not self.at(*ends):
            stmt = self.statement()
            if stmt is not None:
                out.append(stmt)
        return out

    def statement(self):
        tok = self.tok
        line = tok.line
        if self.at(";"):
            self.next()
            return None
        if self.at("IF"):
            self.next()
            branches = [(self.expr(), self.then("THEN", "ELSIF", "ELSE", "END_IF"))]
            orelse: list = []
            while self.at("ELSIF"):
                self.next()
                branches.append((self.expr(), self.then("THEN", "ELSIF", "ELSE", "END_IF")))
            if self.at("ELSE"):
                self.next()
                orelse = self.statements("END_IF")
            self.expect("END_IF")
            self.expect(";")
            return ("if", line, branches, orelse)
        if self.at("CASE"):
            self.next()
            selector = self.expr()
            self.expect("OF")
            cases = []
            orelse = []
            while not self.at("END_CASE", "ELSE"):
                labels = [self.signed_int()]
                while self.at(","):
                    self.next()
                    labels.append(self.signed_int())
                self.expect(":")
                body = []
                while not self.at("END_CASE", "ELSE") and not (
                        self.tok.kind == "int" and self.toks[self.i + 1].text in (":", ",")):
                    stmt = self.statement()
                    if stmt is not None:
                        body.append(stmt)
                cases.append((labels, body))
            if self.at("ELSE"):
                self.next()
                orelse = self.statements("END_CASE")
            self.expect("END_CASE")
            self.expect(";")
            return ("case", line, selector, cases, orelse)
        if self.at("FOR"):
            self.next()
            var = self.ident()
            self.expect(":=")
            start = self.expr()
            self.expect("TO")
            end = self.expr()
            step = 1
            if self.at("BY"):
                self.next()
                step = self.signed_int()
            self.expect("DO")
            body = self.statements("END_FOR")
            self.expect("END_FOR")
            self.expect(";")
            return ("for", line, var, start, end, step, body)
        if self.at("WHILE"):
            self.next()
            cond = self.expr()
            self.expect("DO")
            body = self.statements("END_WHILE")
            self.expect("END_WHILE")
            self.expect(";")
            return ("while", line, cond, body)
        if self.at("EXIT"):
            self.next()
            self.expect(";")
            return ("exit", line)
        target = self.postfix()
        if self.at("("):
            if target[0] != "name":
                raise StError(f"line {line}: only a function block instance can be called")
            self.next()
            args = []
            while not self.at(")"):
                key = self.ident()
                self.expect(":=")
                args.append((key, self.expr()))
                if self.at(","):
                    self.next()
            self.expect(")")
            self.expect(";")
            return ("call", line, target[2], args)
        self.expect(":=")
        value = self.expr()
        self.expect(";")
        return ("assign", line, target, value)

    def then(self, word: str, *ends: str) -> list:
        self.expect(word)
        return self.statements(*ends)

    # -- expressions -------------------------------------------------------------------------
    LEVELS = (("OR",), ("XOR",), ("AND",), ("=", "<>"), ("<", "<=", ">", ">="), ("+", "-"),
              ("*",))

    def expr(self, level: int = 0):
        if level == len(self.LEVELS):
            return self.unary()
        left = self.expr(level + 1)
        while self.at(*self.LEVELS[level]):
            op = self.next()
            right = self.expr(level + 1)
            left = ("bin", op.line, op.text, left, right)
        return left

    def unary(self):
        if self.at("NOT"):
            line = self.next().line
            return ("not", line, self.unary())
        if self.at("-"):
            line = self.next().line
            return ("neg", line, self.unary())
        return self.postfix()

    def postfix(self):
        tok = self.next()
        line = tok.line
        if tok.kind == "op" and tok.text == "(":
            inner = self.expr()
            self.expect(")")
            return inner
        if tok.kind == "kw" and tok.text in ("TRUE", "FALSE"):
            return ("lit", line, "BOOL", tok.text == "TRUE")
        if tok.kind == "int":
            return ("lit", line, ANY_INT, parse_int(tok.text))
        if tok.kind == "typed":
            type_, _, rest = tok.text.partition("#")
            type_ = type_.upper()
            value = parse_int(rest)
            if type_ in BITS and value >> BITS[type_]:
                raise StError(f"line {line}: {tok.text} does not fit a {type_}")
            return ("lit", line, type_, value)
        if tok.kind == "time":
            return ("lit", line, "TIME", parse_time(tok.text))
        if tok.kind != "ident":
            raise StError(f"line {line}: unexpected {tok.text!r} in an expression")
        name = tok.text.upper()
        if self.at("(") and name in FUNCTIONS:
            self.next()
            args = [self.expr()]
            while self.at(","):
                self.next()
                args.append(self.expr())
            self.expect(")")
            return ("func", line, name, args)
        node = ("name", line, name)
        while self.at(".", "["):
            if self.next().text == ".":
                node = ("member", line, node, self.ident())
            else:
                index = self.expr()
                self.expect("]")
                node = ("index", line, node, index)
        return node


FUNCTIONS = {"SHL"}


# --------------------------------------------------------------------------------------------
# Run time: values, standard FBs, instances
# --------------------------------------------------------------------------------------------


class Clock:
    """The injected time every timer reads (microseconds)."""

    def __init__(self) -> None:
        self.now_us = 0


class Instance:
    """A function block or program instance: its variables by upper-case name."""

    __slots__ = ("pou", "vars")

    def __init__(self, pou: str, variables: dict):
        self.pou = pou
        self.vars = variables


class StandardTimer:
    """IEC 61131-3 TON / TOF (ed. 2, 2.5.2.3.4), sampled when called."""

    def __init__(self, kind: str, clock: Clock):
        self.kind = kind
        self.clock = clock

    def new(self) -> Instance:
        return Instance(self.kind, {"IN": False, "PT": 0, "Q": False, "ET": 0, "_RUN": False,
                                    "_START": 0, "_PREV": False})

    def runner(self) -> Callable[[dict, dict], None]:
        """The timer's body as the translated code calls an FB: `run(variables, globals)`.

        One function per kind, reading the clock itself: a timer is called twice a scan per
        monitor, about three million calls in the agreement tests."""
        clock = self.clock
        if self.kind == "TON":
            def ton(v: dict, _globals: dict) -> None:
                if not v["IN"]:
                    v["Q"], v["ET"], v["_RUN"] = False, 0, False
                    return
                now = clock.now_us
                if not v["_RUN"]:  # rising edge of IN: start timing
                    v["_RUN"], v["_START"] = True, now
                et = v["ET"] = min(now - v["_START"], v["PT"])
                v["Q"] = et >= v["PT"]
            return ton

        def tof(v: dict, _globals: dict) -> None:
            if v["IN"]:
                v["Q"], v["ET"], v["_RUN"] = True, 0, False
            elif v["_PREV"] or v["_RUN"]:
                now = clock.now_us
                if not v["_RUN"]:  # falling edge of IN: start timing
                    v["_RUN"], v["_START"] = True, now
                et = v["ET"] = min(now - v["_START"], v["PT"])
                v["Q"] = et < v["PT"]
            v["_PREV"] = v["IN"]
        return tof


TIMER_TYPES = {"TON": {"IN": "BOOL", "PT": "TIME", "Q": "BOOL", "ET": "TIME"},
               "TOF": {"IN": "BOOL", "PT": "TIME", "Q": "BOOL", "ET": "TIME"}}
TIMER_INPUTS = {"IN", "PT"}


# --------------------------------------------------------------------------------------------
# Compilation: types checked, each POU translated once into a Python function
# --------------------------------------------------------------------------------------------
#
# Why translate rather than walk the tree: the agreement tests run the exported code over
# hundreds of thousands of scans, and a tree walk (or a tree of closures) is several times
# slower than the same operations as Python code. The source handed to compile() is built
# here, from the checked syntax tree, never taken from the ST text.


def _default(type_: TypeRef):
    base = type_.name
    if base == "BOOL":
        value: object = False
    elif base in INTS or base in BITS or base == "TIME":
        value = 0
    else:
        value = None  # an FB instance, made when the owner is instantiated
    if type_.array:
        low, high = type_.array
        return [value] * (high - low + 1)
    return value


def _compatible(target: str, value: str) -> bool:
    if target == value:
        return True
    if value == ANY_INT:
        return target in INTS or target in BITS
    return target == "DINT" and value == "INT"


def _ix(k: int, low: int, high: int, line: int) -> int:
    if not low <= k <= high:
        raise StError(f"line {line}: index {k} outside [{low}..{high}]")
    return k - low


def _literal_int(node) -> int | None:
    """The value of an integer literal node (or of a negated one), else None."""
    if node[0] == "neg":
        inner = _literal_int(node[2])
        return None if inner is None else -inner
    if node[0] == "lit" and isinstance(node[3], int) and not isinstance(node[3], bool):
        return node[3]
    return None


def _chk(value: int, low: int, high: int, line: int) -> int:
    if not low <= value <= high:
        raise StError(f"line {line}: overflow ({value})")
    return value


def _loop_guard(line: int) -> None:
    raise StError(f"line {line}: WHILE runs forever")


@dataclass
class Frame:
    """How a POU's names resolve: to its own variables or to the globals (VAR_EXTERNAL)."""

    pou: Pou
    types: dict[str, TypeRef] = field(default_factory=dict)
    external: set[str] = field(default_factory=set)
    sections: dict[str, str] = field(default_factory=dict)
    constants: set[str] = field(default_factory=set)


class _Source:
    """Python lines being written for one POU, with fresh temporary names."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.count = 0

    def temp(self) -> str:
        self.count += 1
        return f"_t{self.count}"

    def add(self, depth: int, text: str) -> None:
        self.lines.append("    " * depth + text)


class Program:
    """A loaded ST file: its POUs, checked and translated, and its configuration."""

    def __init__(self, text: str):
        self.pous, self.config = Parser(text).file()
        self.clock = Clock()
        self.timers = {k: StandardTimer(k, self.clock) for k in TIMER_TYPES}
        self.global_types: dict[str, TypeRef] = {}
        self.global_decls: list[VarDecl] = []
        if self.config is not None:
            for d in self.config.globals:
                if d.name in self.global_types:
                    raise StError(f"line {d.line}: global {d.name} declared twice")
                self.global_types[d.name] = d.type
                self.global_decls.append(d)
        self.frames = {name: self._frame(pou) for name, pou in self.pous.items()}
        # How each FB type runs, called as `run(instance variables, globals)`: its translated
        # body, a standard timer, or a native stand-in (set_native).
        self.fbs: dict[str, Callable[[dict, dict], None]] = {
            k: t.runner() for k, t in self.timers.items()}
        self.code: dict[str, Callable[[dict, dict], None]] = {}
        self._temps = 0  # index and overflow temporaries of the translated code
        for name in self.pous:
            self.code[name] = self._compile_pou(name)
            self.fbs[name] = self.code[name]

    def set_native(self, pou: str, fn: Callable[[Instance, dict], None]) -> None:
        """Run `fn(instance, globals)` instead of the FB's body (the test's stand-ins)."""
        if pou not in self.pous:
            raise KeyError(pou)
        self.fbs[pou] = lambda variables, g: fn(Instance(pou, variables), g)

    def _temp(self) -> str:
        self._temps += 1
        return f"_k{self._temps}"

    # -- declarations ------------------------------------------------------------------------
    def _frame(self, pou: Pou) -> Frame:
        frame = Frame(pou)
        for d in pou.decls:
            if d.name in frame.types:
                raise StError(f"line {d.line}: {d.name} declared twice in {pou.name}")
            if d.section == "VAR_EXTERNAL":
                found = self.global_types.get(d.name)
                if found is None or found != d.type:
                    raise StError(f"line {d.line}: VAR_EXTERNAL {d.name} does not match a "
                                  "global of that type")
                frame.external.add(d.name)
            elif d.type.name not in ("BOOL", "TIME", *INTS, *BITS, *TIMER_TYPES, *self.pous):
                raise StError(f"line {d.line}: unknown type {d.type.name}")
            if d.constant:
                frame.constants.add(d.name)
            frame.types[d.name] = d.type
            frame.sections[d.name] = d.section
        return frame

    def instantiate(self, pou_name: str) -> Instance:
        if pou_name in self.timers:
            return self.timers[pou_name].new()
        pou = self.pous[pou_name]
        frame = self.frames[pou_name]
        variables: dict = {}
        for d in pou.decls:
            if d.section == "VAR_EXTERNAL":
                continue
            if d.type.name in TIMER_TYPES or d.type.name in self.pous:
                if d.type.array:
                    raise StError(f"line {d.line}: arrays of FB instances are not in the subset")
                variables[d.name] = self.instantiate(d.type.name)
                continue
            value = _default(d.type)
            if d.init is not None:
                value = self.constant(d, frame)
            variables[d.name] = value
        return Instance(pou_name, variables)

    def constant(self, d: VarDecl, frame: Frame):
        """The value of an initialiser (literals only in this subset)."""
        def one(node):
            if node[0] == "neg" and node[2][0] == "lit":
                node = ("lit", node[1], node[2][2], -node[2][3])
            if node[0] != "lit":
                raise StError(f"line {d.line}: initial value of {d.name} is not a literal")
            if not _compatible(d.type.name, node[2]):
                raise StError(f"line {d.line}: initial value of {d.name} is {node[2]}, "
                              f"not {d.type.name}")
            return node[3]
        if isinstance(d.init, list):
            if d.type.array is None or len(d.init) != d.type.array[1] - d.type.array[0] + 1:
                raise StError(f"line {d.line}: array initialiser of {d.name} has the wrong "
                              "length")
            return [one(x) for x in d.init]
        if d.type.array is not None:
            raise StError(f"line {d.line}: an array needs a [..] initialiser")
        return one(d.init)

    # -- expressions: (Python source, type name) --------------------------------------------
    def _expr(self, node, frame: Frame) -> tuple[str, str]:
        kind, line = node[0], node[1]
        if kind == "lit":
            return repr(node[3]), node[2]
        if kind in ("name", "member", "index"):
            src, type_, _writable = self._place(node, frame)
            if type_.array is not None:
                raise StError(f"line {line}: a whole array is not a value")
            return src, type_.name
        if kind == "not":
            inner, t = self._expr(node[2], frame)
            if t == "BOOL":
                return f"(not {inner})", "BOOL"
            if t in BITS:
                return f"(~{inner} & {(1 << BITS[t]) - 1})", t
            raise StError(f"line {line}: NOT of a {t}")
        if kind == "neg":
            inner, t = self._expr(node[2], frame)
            if t not in (*INTS, ANY_INT, "TIME"):
                raise StError(f"line {line}: unary minus of a {t}")
            return f"(-{inner})", t
        if kind == "func" and node[2] == "SHL":
            args = node[3]
            if len(args) != 2:
                raise StError(f"line {line}: SHL takes 2 arguments")
            (a, ta), (b, tb) = (self._expr(x, frame) for x in args)
            if ta not in BITS or tb not in (*INTS, ANY_INT):
                raise StError(f"line {line}: SHL({ta}, {tb})")
            return f"(({a} << {b}) & {(1 << BITS[ta]) - 1})", ta
        if kind == "bin":
            return self._binary(node, frame)
        raise StError(f"line {line}: unsupported expression {kind}")

    def _binary(self, node, frame: Frame) -> tuple[str, str]:
        _, line, op, left, right = node
        a, ta = self._expr(left, frame)
        b, tb = self._expr(right, frame)
        if op in ("AND", "OR", "XOR"):
            logical = ta == tb == "BOOL"
            bitwise = (ta in BITS or tb in BITS) and (ta == tb or ANY_INT in (ta, tb))
            if not (logical or bitwise):
                raise StError(f"line {line}: {ta} {op} {tb}")
            t = ta if ta != ANY_INT else tb
            if logical:
                py = {"AND": "and", "OR": "or", "XOR": "!="}[op]
            else:
                py = {"AND": "&", "OR": "|", "XOR": "^"}[op]
            return f"({a} {py} {b})", t
        if op in ("=", "<>", "<", "<=", ">", ">="):
            ok = _compatible(ta, tb) or _compatible(tb, ta)
            if not ok or (op not in ("=", "<>") and ta in ("BOOL", *BITS)):
                raise StError(f"line {line}: {ta} {op} {tb}")
            py = {"=": "==", "<>": "!="}.get(op, op)
            return f"({a} {py} {b})", "BOOL"
        if op in ("+", "-", "*"):
            time_sum = ta == tb == "TIME" and op != "*"
            time_scaled = ta == "TIME" and op == "*" and tb in (*INTS, ANY_INT)
            if time_sum or time_scaled:
                t = "TIME"
            elif ta in (*INTS, ANY_INT) and tb in (*INTS, ANY_INT):
                t = "DINT" if "DINT" in (ta, tb) else ("INT" if "INT" in (ta, tb) else ANY_INT)
            else:
                raise StError(f"line {line}: {ta} {op} {tb}")
            low, high = INTS.get(t, (-TIME_MAX_US, TIME_MAX_US) if t == "TIME" else (0, 0))
            if t == ANY_INT:
                return f"({a} {op} {b})", t
            # in line, as _chk would (a call per sum costs more than the sum): _chk raises
            k = self._temp()
            return (f"({k} if {low} <= ({k} := {a} {op} {b}) <= {high} "
                    f"else _chk({k}, {low}, {high}, {line}))"), t
        raise StError(f"line {line}: operator {op}")

    def _place(self, node, frame: Frame) -> tuple[str, TypeRef, bool]:
        """(Python source, type, writable) of a variable, an FB member or an element."""
        kind, line = node[0], node[1]
        if kind == "name":
            name = node[2]
            type_ = frame.types.get(name)
            if type_ is None:
                raise StError(f"line {line}: unknown name {name} in {frame.pou.name}")
            where = "g" if name in frame.external else "v"
            return f"{where}[{name!r}]", type_, name not in frame.constants
        if kind == "member":
            base, base_type, _ = self._place(node[2], frame)
            member = node[3]
            if base_type.name in TIMER_TYPES:
                members = TIMER_TYPES[base_type.name]
                if member not in members:
                    raise StError(f"line {line}: {base_type.name} has no {member}")
                mtype = TypeRef(members[member])
            elif base_type.name in self.pous:
                inner = self.frames[base_type.name]
                if inner.sections.get(member) not in ("VAR_OUTPUT", "VAR_INPUT"):
                    raise StError(f"line {line}: {member} is not an input or output of "
                                  f"{base_type.name}")
                mtype = inner.types[member]
            else:
                raise StError(f"line {line}: {base_type.name} has no members")
            return f"{base}.vars[{member!r}]", mtype, False
        if kind == "index":
            base, base_type, writable = self._place(node[2], frame)
            if base_type.array is None:
                raise StError(f"line {line}: indexing a {base_type.name}")
            index, ti = self._expr(node[3], frame)
            if ti not in (*INTS, ANY_INT):
                raise StError(f"line {line}: index of type {ti}")
            low, high = base_type.array
            literal = _literal_int(node[3])
            if literal is not None and low <= literal <= high:  # checked here, once
                return f"{base}[{literal - low}]", TypeRef(base_type.name), writable
            # in line, as _ix would (out of bounds, _ix raises at run time)
            k = self._temp()
            offset = k if low == 0 else f"{k} - {low}"
            return (f"{base}[{offset} if {low} <= ({k} := {index}) <= {high} "
                    f"else _ix({k}, {low}, {high}, {line})]", TypeRef(base_type.name),
                    writable)
        raise StError(f"line {line}: not a variable")

    # -- statements ---------------------------------------------------------------------------
    def _compile_pou(self, name: str) -> Callable[[dict, dict], None]:
        frame = self.frames[name]
        out = _Source()
        out.add(0, "def run(v, g):")
        self._block(self.pous[name].body, frame, out, 1, in_loop=False)
        out.add(1, "return None")
        namespace = {"_ix": _ix, "_chk": _chk, "_loop_guard": _loop_guard, "_fbs": None,
                     "StError": StError}
        code = compile("\n".join(out.lines), f"<ST {name}>", "exec")
        exec(code, namespace)  # source built above from the checked tree
        namespace["_fbs"] = self.fbs
        return namespace["run"]

    def _block(self, stmts: list, frame: Frame, out: _Source, depth: int, in_loop: bool):
        before = len(out.lines)
        for s in stmts:
            self._stmt(s, frame, out, depth, in_loop)
        if len(out.lines) == before:
            out.add(depth, "pass")

    def _cond(self, node, frame: Frame) -> str:
        src, t = self._expr(node, frame)
        if t != "BOOL":
            raise StError(f"line {node[1]}: a condition of type {t}")
        return src

    def _stmt(self, s, frame: Frame, out: _Source, depth: int,
              in_loop: bool) -> None:
        kind, line = s[0], s[1]
        if kind == "assign":
            target, ttype, writable = self._place(s[2], frame)
            if not writable:
                raise StError(f"line {line}: cannot assign to this (an FB's member or a "
                              "constant)")
            value, vtype = self._expr(s[3], frame)
            if ttype.array is not None or not _compatible(ttype.name, vtype):
                raise StError(f"line {line}: assigning a {vtype} to a {ttype.name}")
            out.add(depth, f"{target} = {value}")
        elif kind == "call":
            self._call(s, frame, out, depth)
        elif kind == "if":
            for k, (cond, body) in enumerate(s[2]):
                out.add(depth, f"{'if' if k == 0 else 'elif'} {self._cond(cond, frame)}:")
                self._block(body, frame, out, depth + 1, in_loop)
            if s[3]:
                out.add(depth, "else:")
                self._block(s[3], frame, out, depth + 1, in_loop)
        elif kind == "case":
            selector, t = self._expr(s[2], frame)
            if t not in (*INTS, ANY_INT):
                raise StError(f"line {line}: CASE on a {t}")
            temp = out.temp()
            out.add(depth, f"{temp} = {selector}")
            seen: set[int] = set()
            for k, (labels, body) in enumerate(s[3]):
                if seen & set(labels):
                    raise StError(f"line {line}: a CASE label twice")
                seen |= set(labels)
                out.add(depth, f"{'if' if k == 0 else 'elif'} {temp} in {tuple(labels)!r}:")
                self._block(body, frame, out, depth + 1, in_loop)
            if s[4]:
                out.add(depth, "else:" if s[3] else "if True:")
                self._block(s[4], frame, out, depth + 1, in_loop)
        elif kind == "for":
            var, start, end, step, body = s[2], s[3], s[4], s[5], s[6]
            target, vtype, writable = self._place(("name", line, var), frame)
            if vtype.name not in INTS or not writable:
                raise StError(f"line {line}: FOR variable of type {vtype.name}")
            first, t1 = self._expr(start, frame)
            last, t2 = self._expr(end, frame)
            if t1 not in (*INTS, ANY_INT) or t2 not in (*INTS, ANY_INT):
                raise StError(f"line {line}: FOR bounds of types {t1}, {t2}")
            k, stop = out.temp(), out.temp()
            out.add(depth, f"{k} = {first}")
            out.add(depth, f"{stop} = {last}")
            out.add(depth, f"while {k} {'<=' if step > 0 else '>='} {stop}:")
            out.add(depth + 1, f"{target} = {k}")
            self._block(body, frame, out, depth + 1, in_loop=True)
            out.add(depth + 1, f"{k} += {step}")
        elif kind == "while":
            cond = self._cond(s[2], frame)
            count = out.temp()
            out.add(depth, f"{count} = 0")
            out.add(depth, f"while {cond}:")
            self._block(s[3], frame, out, depth + 1, in_loop=True)
            out.add(depth + 1, f"{count} += 1")
            out.add(depth + 1, f"if {count} > {MAX_LOOPS}: _loop_guard({line})")
        elif kind == "exit":
            if not in_loop:
                raise StError(f"line {line}: EXIT outside a loop")
            out.add(depth, "break")
        else:
            raise StError(f"line {line}: unsupported statement {kind}")

    def _call(self, s, frame: Frame, out: _Source, depth: int) -> None:
        line, name, args = s[1], s[2], s[3]
        inst, type_, _ = self._place(("name", line, name), frame)
        if type_.name in TIMER_TYPES:
            inputs = {k: t for k, t in TIMER_TYPES[type_.name].items() if k in TIMER_INPUTS}
        elif type_.name in self.pous and self.pous[type_.name].kind == "FUNCTION_BLOCK":
            inner = self.frames[type_.name]
            inputs = {k: t.name for k, t in inner.types.items()
                      if inner.sections[k] == "VAR_INPUT"}
        else:
            raise StError(f"line {line}: {name} is not a function block instance")
        temps = []
        for key, value_node in args:
            if key not in inputs:
                raise StError(f"line {line}: {type_.name} has no input {key}")
            value, vtype = self._expr(value_node, frame)
            if not _compatible(inputs[key], vtype):
                raise StError(f"line {line}: input {key} given a {vtype}")
            temp = out.temp()
            out.add(depth, f"{temp} = {value}")
            temps.append((key, temp))
        instance = out.temp()
        out.add(depth, f"{instance} = {inst}.vars")
        for key, temp in temps:
            out.add(depth, f"{instance}[{key!r}] = {temp}")
        out.add(depth, f"_fbs[{type_.name!r}]({instance}, g)")


class Runtime:
    """One running configuration: its globals and program instances; `scan()` runs the task."""

    def __init__(self, program: Program):
        if program.config is None:
            raise StError("no CONFIGURATION to run")
        self.program = program
        self.globals: dict = {}
        empty = Frame(Pou("", "", [], [], 0))
        for d in program.global_decls:
            value = _default(d.type)
            if d.init is not None:
                value = program.constant(d, empty)
            self.globals[d.name] = value
        self.instances = {inst: program.instantiate(pou)
                          for inst, _task, pou in program.config.instances}
        self.runs = [(program.code[pou], self.instances[inst].vars)
                     for inst, _task, pou in program.config.instances]

    def scan(self, now_us: int) -> None:
        self.program.clock.now_us = now_us
        for code, variables in self.runs:
            code(variables, self.globals)

    def get(self, path: str):
        """`Safety.Diag_V1.State` or a global's name."""
        return self.getter(path)()

    def getter(self, path: str) -> Callable[[], object]:
        """A reader of `path`, resolved once (instances live as long as the runtime)."""
        variables, key = self._place(path)
        return lambda: variables[key]

    def reader(self, paths: Sequence[str]) -> Callable[[], tuple]:
        """One reader of several variables of one instance (or of the globals), returning
        their values as a tuple: one lookup in C per call instead of a Python call per
        variable (the agreement tests read a dozen of them on every one of 300,000 scans)."""
        places = [self._place(path) for path in paths]
        variables = places[0][0]
        if any(where is not variables for where, _ in places):
            raise ValueError(f"not one instance: {list(paths)}")
        take = itemgetter(*(key for _, key in places))
        if len(places) == 1:
            return lambda: (take(variables),)
        return lambda: take(variables)

    def _place(self, path: str) -> tuple[dict, str]:
        """The variables holding `path`, and its key in them."""
        parts = path.upper().split(".")
        if len(parts) == 1:
            if parts[0] not in self.globals:
                raise KeyError(path)
            return self.globals, parts[0]
        inst = self.instances[parts[0]]
        for part in parts[1:-1]:
            inst = inst.vars[part]
        if parts[-1] not in inst.vars:
            raise KeyError(path)
        return inst.vars, parts[-1]

    def set(self, name: str, value) -> None:
        key = name.upper()
        if key not in self.globals:
            raise KeyError(name)
        self.globals[key] = value
