"""What a loaded project holds: plain, immutable data, already validated.

The loader builds these from YAML; the engine compiles them. Nothing here knows about files
beyond the positions kept for error messages and explanations. Every section's types are
here, its parser in its own module (hmi/project/diagnosers.py reads `diagnosers:` into
DiagnoserSpec): the parsers import this module, and this module imports none of them.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hmi.errors import Diagnostic, SourcePos
from hmi.logic.expr import Expr, Literal, to_text
from hmi.logic.rename import rename_node, renamed_source
from hmi.project.injection import Injection
from hmi.project.texts import ProjectTexts
from hmi.timefmt import format_duration

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
    # inputs: the device's own fault signal (a drive fault relay): 1 means the device is
    # halted by a malfunction, the root cause of whatever it then fails to do
    fault: bool = False


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
class DeviceSpec:
    """One simulated device: a model, its parameters, and its ports bound to project variables."""

    name: str
    model: str
    params: dict[str, Any]
    ports: dict[str, str]  # model port -> project variable
    pos: SourcePos


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


# --------------------------------------------------------------------------------------------
# Project
# --------------------------------------------------------------------------------------------


# -- the `diagnosers:` section (hmi/project/diagnosers.py) ---------------------------------


FLAG_PREFIX = "def_"  # a partition's flag: def_<partition>
FILTERED_SUFFIX = "_filter"  # a reconstructed sensor: <sensor>_filter


@dataclass(frozen=True)
class Partition:
    """A group of labels of one component (000 §2.1 Π_f), and what its flag drives."""

    name: str
    labels: tuple[str, ...]
    sensor: str | None  # sensor partition: this input is reconstructed while flagged
    estimate: str | None  # ... from this Boolean (observer, timer)
    actuators: tuple[str, ...]  # actuator partition: these outputs are masked while flagged
    description: str
    pos: SourcePos

    @property
    def flag(self) -> str:
        return FLAG_PREFIX + self.name

    @property
    def filtered(self) -> str | None:
        return self.sensor + FILTERED_SUFFIX if self.sensor else None


@dataclass(frozen=True)
class DiagState:
    """A state of the automaton; its decision is its labels (none: a normal state)."""

    name: str
    labels: tuple[str, ...]
    description: str
    pos: SourcePos

    @property
    def faulty(self) -> bool:
        return bool(self.labels)


@dataclass(frozen=True)
class DiagTransition:
    """An event transition (`when` within [tmin, tmax)) or a timeout (`after`)."""

    index: int  # 1-based, in file order
    source: str
    target: str
    when: Expr | None
    tmin_us: int = 0
    tmax_us: int | None = None  # None: no upper bound
    after_us: int | None = None
    description: str = ""
    pos: SourcePos = field(default_factory=lambda: SourcePos("?"))

    @property
    def is_timeout(self) -> bool:
        return self.when is None

    def window_text(self) -> str:
        if self.is_timeout:
            return f"after {format_duration(self.after_us or 0)}"
        if self.tmin_us == 0 and self.tmax_us is None:
            return ""
        upper = "inf" if self.tmax_us is None else format_duration(self.tmax_us)
        return f"within [{format_duration(self.tmin_us)}, {upper})"

    def text(self) -> str:
        """`N2 -> N3 on not fsc within [0s, 300ms)`: for reports and the operator."""
        if self.is_timeout:
            return f"{self.source} -> {self.target} {self.window_text()}"
        window = self.window_text()
        return f"{self.source} -> {self.target} on {self.when}" + (f" {window}" if window
                                                                    else "")


@dataclass(frozen=True)
class ResyncRule:
    when: Expr
    target: str
    pos: SourcePos


@dataclass(frozen=True)
class HighLevelRule:
    """One rule of a global specification: while the local decision holds, `when` decides
    the label `decide`, for the reason `because` (plain words for the operator)."""

    when: Expr
    decide: str
    because: str
    pos: SourcePos


@dataclass(frozen=True)
class HighLevelSpec:
    """A global specification of the High Level Diagnoser (000 §2.1 step 4): what several
    devices show together refines one local diagnoser's ambiguous decision."""

    name: str
    description: str
    diagnoser: str
    decision: tuple[str, ...]  # the local decision it refines (exactly these labels)
    rules: tuple[HighLevelRule, ...]
    pos: SourcePos


@dataclass(frozen=True)
class DiagnoserSpec:
    name: str
    description: str
    device: str | None
    labels: dict[str, str]  # label -> operator text, in file order
    partitions: tuple[Partition, ...]
    initial: str
    states: tuple[DiagState, ...]
    transitions: tuple[DiagTransition, ...]
    resync: tuple[ResyncRule, ...]
    pos: SourcePos
    variant: str = ""  # the variant loaded, when the diagnoser declares several
    variants: tuple[str, ...] = ()

    def state(self, name: str) -> DiagState:
        return next(s for s in self.states if s.name == name)

    def partition_of(self, label: str) -> Partition | None:
        return next((p for p in self.partitions if label in p.labels), None)

    def flags_of(self, state: DiagState) -> tuple[str, ...]:
        """The partition flags a state's decision sets."""
        return tuple(p.flag for p in self.partitions if set(p.labels) & set(state.labels))

    def label_text(self, label: str) -> str:
        return self.labels.get(label, label)

    def decision_text(self, labels: tuple[str, ...]) -> str:
        """'F1 (fsc stuck at 0) or F13 (valve blocked between positions)'."""
        return " or ".join(f"{lab} ({self.label_text(lab)})" for lab in labels)

    @property
    def exprs(self) -> tuple[Expr, ...]:
        return tuple(t.when for t in self.transitions if t.when is not None) + tuple(
            r.when for r in self.resync)


# -- the `monitors:` section (hmi/project/monitors.py) -------------------------------------


@dataclass(frozen=True)
class TaskMonitor:
    """One interruptible task: its signals and its normal/acceptable durations (µs)."""

    name: str
    label: str  # the fault label raised by the monitor
    description: str
    device: str | None  # the device as the operator knows it
    start: Expr
    end: Expr
    interrupted: Expr | None  # level form: the task is suspended while this holds
    interrupt: Expr | None  # event form: suspension ...
    resume: Expr | None  # ... and resumption
    alpha_us: int
    beta_us: int
    gamma_us: int
    pos: SourcePos

    @property
    def exprs(self) -> tuple[Expr, ...]:
        return tuple(e for e in (self.start, self.end, self.interrupted, self.interrupt,
                                 self.resume) if e is not None)

    @property
    def title(self) -> str:
        """How the operator knows the task: its description, or device and name."""
        return self.description or (f"{self.device}: {self.name}" if self.device else self.name)

    def windows_text(self) -> str:
        a, b, g = (format_duration(v) for v in (self.alpha_us, self.beta_us, self.gamma_us))
        return f"normal [{a}, {b}], acceptable [{a}, {g}]"


# -- the `recovery:` section (hmi/project/recovery.py) -------------------------------------


@dataclass(frozen=True)
class RecoveryAction:
    """An output the step turns on, while `condition` holds (None: always)."""

    output: str
    condition: Expr | None


@dataclass(frozen=True)
class RecoveryStep:
    description: str
    actions: tuple[RecoveryAction, ...]
    until: Expr
    # `until` must hold this long (a table rolled for a second with no box seen is empty).
    for_us: int = 0


@dataclass(frozen=True)
class RecoveryNeed:
    """When the cell needs the procedure: `when` held for `for_us`; `text` says it plainly."""

    when: Expr
    for_us: int
    text: str


@dataclass(frozen=True)
class RecoveryProcedure:
    name: str
    device: str  # as the operator knows it ("Valve V1"), or the project's name (the cell)
    description: str  # what it does, in the operator's words
    steps: tuple[RecoveryStep, ...]
    timeout_us: int
    relaxes: tuple[str, ...]  # project constraints not enforced while it runs
    constraints: tuple[Constraint, ...]  # its own
    needed: RecoveryNeed | None
    pos: SourcePos
    # The program's set/reset observers it brings back to their initial value when it is
    # done (a turntable emptied: "a box lies on the table" is false whatever edge was missed).
    resets: tuple[str, ...] = ()

    @property
    def exprs(self) -> tuple[Expr, ...]:
        """Every expression it evaluates (the engine sizes its history on them)."""
        out: list[Expr] = [c.expr for c in self.constraints]
        if self.needed is not None:
            out.append(self.needed.when)
        for step in self.steps:
            out.append(step.until)
            out.extend(a.condition for a in step.actions if a.condition is not None)
        return tuple(out)

    @property
    def outputs(self) -> tuple[str, ...]:
        """The outputs it drives, in the order its steps name them."""
        seen: dict[str, None] = {}
        for step in self.steps:
            for action in step.actions:
                seen.setdefault(action.output)
        return tuple(seen)


# -- the `scenarios:` section (hmi/project/scenarios.py) -----------------------------------


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    injections: tuple[Injection, ...]
    duration_us: int | None  # how long `run --scenario` runs when --for is not given
    pos: SourcePos


# -- the `campaign:` section (hmi/project/campaign.py) -------------------------------------


@dataclass(frozen=True)
class CampaignScenario:
    """One fault of the campaign, injected at one instant."""

    fault: str
    device: str | None
    at_us: int
    phase: str  # why this instant: the phase of the cycle where the symptom appears
    table: bool  # counted in the 3x3 table (one per fault), or extra evidence
    pos: SourcePos

    @property
    def name(self) -> str:
        prefix = f"{self.device}." if self.device else ""
        return f"{prefix}{self.fault}@{format_duration(self.at_us)}"


@dataclass(frozen=True)
class CampaignSpec:
    length_us: int
    window_us: int
    counter: str
    scenarios: tuple[CampaignScenario, ...]
    pos: SourcePos
    paper: bool = True  # compare the counts with 000 Table 1 (a campaign of the CISPI valve)


# -- the `components:` section (hmi/project/components.py, component_file.py) --------------


@dataclass(frozen=True)
class Parameter:
    """A formal parameter: a variable the component expects the project to provide."""

    name: str
    kind: str  # "input" or "output"
    description: str
    pos: SourcePos


@dataclass(frozen=True)
class ComponentDef:
    """A component file, validated once however many instances use it."""

    name: str
    description: str
    file: str  # as displayed in messages
    path: Path
    parameters: dict[str, Parameter]
    timers: tuple[str, ...]
    observers: tuple[str, ...]
    constraints: tuple[str, ...]
    partitions: tuple[tuple[str, str | None], ...]  # (partition, its formal sensor or None)
    labels: tuple[str, ...]

    @property
    def has_diagnoser(self) -> bool:
        return bool(self.partitions)

    def namespace(self) -> dict[str, str]:
        """Every name the component's expressions may read, with its kind."""
        names = {p.name: p.kind for p in self.parameters.values()}
        names.update(dict.fromkeys(self.timers, "timer"))
        names.update(dict.fromkeys(self.observers, "observer"))
        for partition, sensor in self.partitions:
            names[FLAG_PREFIX + partition] = "flag"
            if sensor:
                names[sensor + FILTERED_SUFFIX] = "filtered"
        return names


@dataclass(frozen=True)
class ComponentInstance:
    """One use of a component by a project: its bindings and the names it gives."""

    name: str
    component: ComponentDef
    device: str
    bind: dict[str, str]  # formal parameter -> project variable
    pos: SourcePos  # the instance's key in the project

    @property
    def prefix(self) -> str:
        return f"{self.name}_"

    @property
    def context(self) -> str:
        return f"in component {self.name} of {self.pos}"

    def own(self, name: str) -> str:
        """The project name of one of the component's own items (timer, constraint...)."""
        return self.prefix + name

    @property
    def renames(self) -> dict[str, str]:
        """Component name -> project name, for every name an expression may read."""
        out = dict(self.bind)
        comp = self.component
        out.update({n: self.own(n) for n in (*comp.timers, *comp.observers)})
        for partition, sensor in comp.partitions:
            out[FLAG_PREFIX + partition] = FLAG_PREFIX + self.own(partition)
            if sensor:
                out[sensor + FILTERED_SUFFIX] = self.bind[sensor] + FILTERED_SUFFIX
        return out

    def declared(self) -> list[tuple[str, str, str]]:
        """(project name, what it is, its name in the component) for every name it adds."""
        comp = self.component
        out = [(self.own(n), "timer", n) for n in comp.timers]
        out += [(self.own(n), "observer", n) for n in comp.observers]
        out += [(self.own(n), "constraint", n) for n in comp.constraints]
        if comp.has_diagnoser:
            out.append((self.name, "diagnoser", "diagnoser"))
        for partition, sensor in comp.partitions:
            out.append((FLAG_PREFIX + self.own(partition), "partition flag",
                        FLAG_PREFIX + partition))
            if sensor:
                out.append((self.bind[sensor] + FILTERED_SUFFIX, "filtered sensor",
                            sensor + FILTERED_SUFFIX))
        return out

    def rename_expr(self, expr: Expr) -> Expr:
        """The expression with every name renamed for this instance, positions kept.

        The tree is renamed node by node (what the engine compiles); the source text shown in
        reports is rebuilt from the identifiers' spans in Python's own parse of it, so
        `rise(C) and not fso_filter` reads `rise(C1) and not fso1_filter`.
        """
        renames = self.renames
        root = rename_node(expr.root, renames)
        source = renamed_source(expr.source, renames) or to_text(root)
        return Expr(source, root, expr.pos)


# -- the project ----------------------------------------------------------------------------

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
    high_level: tuple[HighLevelSpec, ...] = ()  # the High Level Diagnoser's specifications
    monitors: tuple[TaskMonitor, ...] = ()
    scenarios: tuple[Scenario, ...] = ()
    campaign: CampaignSpec | None = None
    explanations: ProjectTexts | None = None  # None: the built-in texts only
    components: tuple[ComponentInstance, ...] = ()
    recovery: tuple[RecoveryProcedure, ...] = ()  # the ways back after a fault
    warnings: tuple[Diagnostic, ...] = ()  # what the loader warned about (plchmi check)
    check_sections: tuple[tuple[str, ...], ...] = ()  # more `plchmi check` sections
    # The diagnosers file loaded in place of the project's (`--diagnoser FILE.yaml`), if any.
    diagnosers_file: str = ""

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
