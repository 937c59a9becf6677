"""The in-memory PLC model every export target is written from (ESCET plcgen's structure).

One model, several writers: :mod:`hmi.export.build` turns a project into a
:class:`PlcProject` (types, POUs with their variable lists and Structured Text bodies, the
global variables, a configuration with its task); :mod:`hmi.export.st` and
:mod:`hmi.export.plcopen` write it as IEC 61131-3 Structured Text and as PLCopen TC6 XML.
Bodies are trees, not text, so each writer renders them its own way (the XML writer embeds
the same ST) and nothing upstream has to know about either syntax.

Only what the builders need is modelled: the ST subset the export emits (assignments,
IF/ELSIF/ELSE, CASE, FOR, WHILE, EXIT, FB calls; Boolean, bit-string, integer and TIME
expressions; arrays of one dimension).
"""

from __future__ import annotations

from dataclasses import dataclass, field

# --------------------------------------------------------------------------------------------
# Types
# --------------------------------------------------------------------------------------------

ELEMENTARY = ("BOOL", "INT", "DINT", "TIME", "WORD", "DWORD", "LWORD")
BIT_WIDTH = {"WORD": 16, "DWORD": 32, "LWORD": 64}


@dataclass(frozen=True)
class Elementary:
    name: str  # one of ELEMENTARY


@dataclass(frozen=True)
class Derived:
    """A function block type (TON, TOF or one of the project's)."""

    name: str


@dataclass(frozen=True)
class Array:
    lower: int
    upper: int
    element: Elementary


PlcType = Elementary | Derived | Array

BOOL = Elementary("BOOL")
INT = Elementary("INT")
DINT = Elementary("DINT")
TIME = Elementary("TIME")


def bits_type(count: int) -> Elementary:
    """The smallest bit string holding `count` bits (callers check the 64-bit limit)."""
    return Elementary("DWORD" if count <= 32 else "LWORD")


# --------------------------------------------------------------------------------------------
# Expressions
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Name:
    id: str


@dataclass(frozen=True)
class Member:
    """`base.member`: an output of an FB instance (`Clock.ET`)."""

    base: Expr
    member: str


@dataclass(frozen=True)
class Index:
    base: Expr
    index: Expr


@dataclass(frozen=True)
class BoolLit:
    value: bool


@dataclass(frozen=True)
class IntLit:
    value: int


@dataclass(frozen=True)
class TimeLit:
    ms: int


@dataclass(frozen=True)
class BitsLit:
    """A typed bit-string literal, written `DWORD#16#...`."""

    value: int
    type: str  # WORD, DWORD, LWORD


@dataclass(frozen=True)
class Unary:
    op: str  # NOT, -
    operand: Expr


@dataclass(frozen=True)
class Binary:
    op: str  # OR XOR AND = <> < <= > >= + - *
    left: Expr
    right: Expr


@dataclass(frozen=True)
class Call:
    """A standard function call with positional arguments (SHL)."""

    func: str
    args: tuple[Expr, ...]


Expr = Name | Member | Index | BoolLit | IntLit | TimeLit | BitsLit | Unary | Binary | Call

TRUE = BoolLit(True)
FALSE = BoolLit(False)


def and_(*operands: Expr) -> Expr:
    """The conjunction of `operands` (TRUE when there are none)."""
    return _fold("AND", operands, TRUE)


def or_(*operands: Expr) -> Expr:
    return _fold("OR", operands, FALSE)


def _fold(op: str, operands: tuple[Expr, ...], empty: Expr) -> Expr:
    if not operands:
        return empty
    result = operands[0]
    for operand in operands[1:]:
        result = Binary(op, result, operand)
    return result


def not_(operand: Expr) -> Expr:
    return Unary("NOT", operand)


def eq(left: Expr, right: Expr) -> Expr:
    return Binary("=", left, right)


def n(name: str) -> Name:
    return Name(name)


# --------------------------------------------------------------------------------------------
# Statements
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Assign:
    target: Expr
    value: Expr


@dataclass(frozen=True)
class If:
    branches: tuple[tuple[Expr, tuple[Stmt, ...]], ...]  # IF, then ELSIF ...
    orelse: tuple[Stmt, ...] = ()


@dataclass(frozen=True)
class Case:
    selector: Expr
    cases: tuple[tuple[tuple[int, ...], tuple[Stmt, ...]], ...]
    orelse: tuple[Stmt, ...] = ()


@dataclass(frozen=True)
class For:
    var: str
    start: Expr
    end: Expr
    body: tuple[Stmt, ...]
    step: int = 1


@dataclass(frozen=True)
class While:
    cond: Expr
    body: tuple[Stmt, ...]


@dataclass(frozen=True)
class Exit:
    pass


@dataclass(frozen=True)
class FbCall:
    """`instance(IN := ..., PT := ...);` (inputs in the given order)."""

    instance: str
    inputs: tuple[tuple[str, Expr], ...] = ()


@dataclass(frozen=True)
class Comment:
    text: str


Stmt = Assign | If | Case | For | While | Exit | FbCall | Comment


def if_(cond: Expr, *then: Stmt, orelse: tuple[Stmt, ...] = ()) -> If:
    return If(((cond, tuple(then)),), orelse)


# --------------------------------------------------------------------------------------------
# Declarations and POUs
# --------------------------------------------------------------------------------------------

SECTIONS = ("input", "output", "inout", "external", "local", "global")


@dataclass(frozen=True)
class ArrayInit:
    values: tuple[Expr, ...]


@dataclass(frozen=True)
class Var:
    name: str
    type: PlcType
    initial: Expr | ArrayInit | None = None
    address: str | None = None  # %IX0.0, %QX0.1
    comment: str = ""


@dataclass(frozen=True)
class VarBlock:
    section: str  # one of SECTIONS
    vars: tuple[Var, ...]
    constant: bool = False


@dataclass(frozen=True)
class Pou:
    name: str
    kind: str  # "functionBlock" or "program" (PLCopen's pouType spelling)
    blocks: tuple[VarBlock, ...]
    body: tuple[Stmt, ...]
    comment: str = ""  # why it exists and how to call it; written as a header

    def variables(self, section: str) -> tuple[Var, ...]:
        return tuple(v for b in self.blocks if b.section == section for v in b.vars)


@dataclass(frozen=True)
class Task:
    name: str
    interval_ms: int
    priority: int


@dataclass(frozen=True)
class ProgramInstance:
    name: str
    task: str
    program: str  # the PROGRAM's POU name


@dataclass(frozen=True)
class Configuration:
    name: str
    resource: str
    globals: tuple[VarBlock, ...]
    tasks: tuple[Task, ...]
    instances: tuple[ProgramInstance, ...]


@dataclass(frozen=True)
class PlcProject:
    name: str
    pous: tuple[Pou, ...]
    configuration: Configuration
    comment: str = ""  # the file header: what this is, where it came from, what was renamed
    summary: tuple[str, ...] = ()  # what was exported and the scan budget, for the CLI
    # What each project thing is called in the code (IEC identifiers are case-insensitive, so
    # `plate_open` and `PLATE_OPEN` cannot both keep their names): a project variable's name
    # -> its global; "Filter", "Memory", "Diag_<D>", "Mon_<task>" -> the program's instance;
    # "<D>.<label>" -> that diagnoser FB's output for the label.
    symbols: dict[str, str] = field(default_factory=dict, compare=False)
    # The control law's GRAFCET as an SFC chart (hmi/export/sfc.py): the PLCopen XML carries
    # it as a POU of its own, for the PLC's editor; the cycle runs the control FB.
    charts: tuple[SfcChart, ...] = ()

    def pou(self, name: str) -> Pou:
        return next(p for p in self.pous if p.name == name)


# SFC charts (hmi/export/sfc.py builds them, hmi/export/plcopen.py writes them)


@dataclass(frozen=True)
class SfcAction:
    qualifier: str  # N, S, R
    variable: str  # the variable it drives (FOV_x, a memory)
    condition: str | None = None  # a conditional N action's condition, in ST


@dataclass(frozen=True)
class SfcStep:
    name: str
    initial: bool
    actions: tuple[SfcAction, ...]
    comment: str = ""


@dataclass(frozen=True)
class SfcTransition:
    sources: tuple[str, ...]
    targets: tuple[str, ...]
    condition: str  # ST
    comment: str = ""


@dataclass(frozen=True)
class SfcChart:
    """A GRAFCET as an SFC POU: its variables (the globals it reads and drives, the values
    back in time as inputs) and its network."""

    name: str
    steps: tuple[SfcStep, ...]
    transitions: tuple[SfcTransition, ...]
    blocks: tuple[VarBlock, ...]
    comment: str = ""
