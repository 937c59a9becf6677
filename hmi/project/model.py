"""What a loaded project holds: plain, immutable data, already validated.

The loader builds these from YAML; the engine compiles them. Nothing here knows about files
beyond the positions kept for error messages and explanations.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hmi.errors import Diagnostic, SourcePos
from hmi.logic.expr import Expr, Literal

if TYPE_CHECKING:  # the sections' own types (they import this module)
    from hmi.project.campaign import CampaignSpec
    from hmi.project.components import ComponentInstance
    from hmi.project.diagnosers import DiagnoserSpec
    from hmi.project.monitors import TaskMonitor
    from hmi.project.recovery import RecoveryProcedure
    from hmi.project.scenarios import Scenario
    from hmi.project.texts import ProjectTexts

# The closed vocabularies of the model, as types: mypy (strict, CI) refuses a misspelt kind
# or policy wherever one is compared or built. At run time they are the plain strings the
# project file holds (the loader checks them against these same lists).
VariableKind = typing.Literal["input", "output", "memory"]
TimerKind = typing.Literal["TON", "TOF"]
ActionKind = typing.Literal["N", "S", "R"]
ConstraintKind = typing.Literal["simple", "combined"]
PlantKind = typing.Literal["sim", "modbus"]
PolicyName = typing.Literal["monitor", "block", "correct"]
SolverName = typing.Literal["exact", "paper"]

# --------------------------------------------------------------------------------------------
# I/O and memory
# --------------------------------------------------------------------------------------------

TABLES = {
    "coil": "coil",
    "di": "discrete input",
    "hr": "holding register bit",
    "ir": "input register bit",
}
READ_ONLY_TABLES = {"di", "ir"}


@dataclass(frozen=True)
class PlantAddress:
    """Where a variable lives on a Modbus device: a table, a 0-based index, a bit for registers."""

    table: str  # coil, di, hr, ir
    index: int
    bit: int | None = None

    def __str__(self) -> str:
        return f"{self.table}:{self.index}" + (f".{self.bit}" if self.bit is not None else "")


@dataclass(frozen=True)
class Variable:
    name: str
    kind: VariableKind
    description: str
    safe: bool = False  # outputs: the value written in the safe state; memories: initial
    address: PlantAddress | None = None
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))
    device: str | None = None  # the plant device this variable belongs to, for explanations


@dataclass(frozen=True)
class Timer:
    """IEC 61131-3 TON / TOF: Q follows IN after PT (TON) or stays PT after IN falls (TOF)."""

    name: str
    kind: TimerKind
    input: Expr
    preset_us: int
    description: str
    pos: SourcePos


@dataclass(frozen=True)
class Observer:
    """A Boolean function of the plant's history (001): either an expression or a set/reset."""

    name: str
    description: str
    expr: Expr | None = None
    set: Expr | None = None
    reset: Expr | None = None
    initial: bool = False
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))


# --------------------------------------------------------------------------------------------
# Control law
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Equation:
    """`target = expr`, or a memory `target = not reset and (set or target)` (reset wins)."""

    target: str
    expr: Expr | None = None
    set: Expr | None = None
    reset: Expr | None = None
    set_dominant: bool = False
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))


@dataclass(frozen=True)
class Action:
    """A step action: continuous (N, optionally conditional) or stored on activation (S/R)."""

    kind: ActionKind  # continuous (N), set (S), reset (R)
    target: str
    condition: Expr | None = None
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))


@dataclass(frozen=True)
class Step:
    number: int
    name: str  # the activity variable, X<number>
    initial: bool
    description: str
    actions: tuple[Action, ...]
    pos: SourcePos
    # S7-GRAPH's supervision: active longer than this in automatic mode, the program is
    # stuck there (an alarm, hmi.explain.sequence); None: not supervised.
    supervision_us: int | None = None


@dataclass(frozen=True)
class Transition:
    number: int
    sources: tuple[str, ...]  # step variables
    targets: tuple[str, ...]
    receptivity: Expr
    description: str
    pos: SourcePos


@dataclass(frozen=True)
class Grafcet:
    steps: tuple[Step, ...]
    transitions: tuple[Transition, ...]
    pos: SourcePos


@dataclass(frozen=True)
class ControlLaw:
    """One variant of the functional program (e.g. `normal`, `faulty`)."""

    name: str
    description: str
    equations: tuple[Equation, ...]
    grafcet: Grafcet | None
    pos: SourcePos

    def driven_outputs(self) -> set[str]:
        targets = {eq.target for eq in self.equations}
        if self.grafcet:
            targets |= {a.target for s in self.grafcet.steps for a in s.actions if a.kind == "N"}
        return targets


# --------------------------------------------------------------------------------------------
# Safety constraints
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Constraint:
    """A monomial that must be FALSE at the end of every scan (000 eq. 1-2, 004 eq. 1-4).

    `kind` is "simple" (one output at t: CSs) or "combined" (several: CSc), found by the
    loader. For a simple constraint, `output_positive` tells its form: o.h0 (True: the
    output must be 0 when h0 holds) or not(o).h1 (False: the output must be 1).
    """

    name: str
    expr: Expr
    literals: tuple[Literal, ...]
    kind: ConstraintKind
    outputs: tuple[str, ...]
    description: str
    pos: SourcePos
    output_positive: bool | None = None
    texts: dict[str, Any] = field(default_factory=dict, compare=False, hash=False)

    @property
    def output_literals(self) -> tuple[Literal, ...]:
        return tuple(lit for lit in self.literals if lit.depth == 0 and lit.name in self.outputs)

    @property
    def context_literals(self) -> tuple[Literal, ...]:
        """The literals over uncontrollable variables Y (everything but outputs at t)."""
        return tuple(lit for lit in self.literals
                     if not (lit.depth == 0 and lit.name in self.outputs))


# --------------------------------------------------------------------------------------------
# Plant
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Tolerance:
    """The range a parameter of a real device spans (wear, temperature, supply, the part
    bought), which the project is built for: every value from `low` to `high` (the nominal,
    the parameter's value, among them). hmi/project/tolerances.py reads it."""

    param: str
    low: float
    high: float
    nominal: float
    kind: str  # the parameter's: "duration" (µs) or "number"
    text: str  # as written: "±20%", "[0ms, 20ms]"
    pos: SourcePos

    def span(self) -> str:
        """`1.6s to 2.4s`, `0.05 to 0.95`."""
        if self.kind == "duration":
            from hmi.timefmt import format_duration
            return f"{format_duration(int(self.low))} to {format_duration(int(self.high))}"
        return f"{self.low:g} to {self.high:g}"


@dataclass(frozen=True)
class DeviceSpec:
    """One simulated device: a model, its parameters, and its ports bound to project variables."""

    name: str
    model: str
    params: dict[str, Any]
    ports: dict[str, str]  # model port -> project variable
    pos: SourcePos
    tolerances: tuple[Tolerance, ...] = ()  # the ranges the project is built for


@dataclass(frozen=True)
class PlantSpec:
    kind: PlantKind
    devices: tuple[DeviceSpec, ...] = ()
    host: str = "127.0.0.1"
    port: int = 502
    unit: int = 1
    timeout_us: int = 1_000_000
    read_gap: int = 8  # unused addresses a read may span to save a request
    write_refresh_us: int = 1_000_000  # outputs are rewritten in full at least this often
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))
    # How late a scan may start after its nominal instant (the controller's tolerance: a
    # scan k reads its inputs somewhere in [k * period, k * period + scan_jitter)).
    scan_jitter_us: int = 0
    jitter_pos: SourcePos | None = None

    @property
    def tolerances(self) -> tuple[tuple[str, Tolerance], ...]:
        """(device, tolerance) of every device, in declaration order."""
        return tuple((d.name, t) for d in self.devices for t in d.tolerances)


# --------------------------------------------------------------------------------------------
# Project
# --------------------------------------------------------------------------------------------


# The corrector's step budget per scan (`solver_budget:`, `--solver-budget`): below the
# minimum even a one-constraint repair could not finish; the maximum is seconds of search.
MIN_SOLVER_BUDGET = 100
MAX_SOLVER_BUDGET = 10_000_000


@dataclass(frozen=True)
class Project:
    name: str
    description: str
    path: Path
    scan_period_us: int
    inputs: tuple[Variable, ...]
    outputs: tuple[Variable, ...]
    memories: tuple[Variable, ...]
    timers: tuple[Timer, ...]
    observers: tuple[Observer, ...]
    controls: dict[str, ControlLaw]
    default_control: str
    constraints: tuple[Constraint, ...]
    policy: PolicyName
    plant: PlantSpec
    pos: SourcePos
    files: tuple[str, ...] = ()
    solver: SolverName = "exact"  # the corrector's search strategy
    # The corrector's search budget per scan, in steps (hmi.engine.solver); None: the default
    # for the scan period (solver.default_budget).
    solver_budget: int | None = None
    # The sections read by their own modules (hmi/project/<section>.py).
    diagnosers: tuple[DiagnoserSpec, ...] = ()
    monitors: tuple[TaskMonitor, ...] = ()
    scenarios: tuple[Scenario, ...] = ()
    campaign: CampaignSpec | None = None
    explanations: ProjectTexts | None = None  # None: the built-in texts only
    components: tuple[ComponentInstance, ...] = ()
    recovery: tuple[RecoveryProcedure, ...] = ()  # the ways back after a fault (issue 19)
    warnings: tuple[Diagnostic, ...] = ()  # what the loader warned about (plchmi check)
    check_sections: tuple[tuple[str, ...], ...] = ()  # more `plchmi check` sections

    @property
    def simple_constraints(self) -> tuple[Constraint, ...]:
        return tuple(c for c in self.constraints if c.kind == "simple")

    @property
    def combined_constraints(self) -> tuple[Constraint, ...]:
        return tuple(c for c in self.constraints if c.kind == "combined")

    def variable(self, name: str) -> Variable | None:
        for var in (*self.inputs, *self.outputs, *self.memories):
            if var.name == name:
                return var
        return None

    def describe(self, name: str) -> str:
        """The operator-facing description of any named thing, or the name itself."""
        var = self.variable(name)
        if var is not None and var.description:
            return var.description
        items: tuple[Timer | Observer, ...] = (*self.timers, *self.observers)
        for item in items:
            if item.name == name and item.description:
                return item.description
        for spec in self.diagnosers:  # flags, filtered sensors
            for p in spec.partitions:
                if name == p.filtered and p.sensor:
                    return f"{self.describe(p.sensor)}, as the filter reads it"
                if name == p.flag:
                    return (f"{spec.device or spec.name}: {p.description or p.name} "
                            "distrusted by the diagnoser")
        return name

    def control(self, name: str | None = None) -> ControlLaw:
        return self.controls[name or self.default_control]


POLICIES: tuple[PolicyName, ...] = typing.get_args(PolicyName)
