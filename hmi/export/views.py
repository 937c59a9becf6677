"""What the builders share: how a POU names the values it reads, expressions, durations.

A POU reads a project value `x` at some depth: `x` now, `prev(x)` one scan back, `prev(x, n)`
n scans back. Each (name, depth) a POU reads becomes one of its variables (`x`, `prev_x`,
`prev3_x`), allocated in the POU's scope; the program that calls it wires each of those
variables to the value it stands for at that point of the scan.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from hmi.errors import Diagnostic, ProjectError, SourcePos
from hmi.export import model as m
from hmi.export.names import Scope
from hmi.logic.expr import And, Const, Node, Not, Or, Var

# TON's preset when a timer only measures: the longest round number of days a 32-bit TIME
# (milliseconds) holds. Times in states and stopwatches saturate there.
TMAX_MS = 24 * 86_400_000


@dataclass(frozen=True)
class Block:
    """A built FB and how to wire it: the inputs through which it reads project values, by
    (name, depth); the outputs it gives project values by name; its other ports by role."""

    pou: m.Pou
    inputs: dict[tuple[str, int], str]
    outputs: dict[str, str]
    ports: dict[str, str] = field(default_factory=dict)
    reset_reads: tuple[tuple[str, int], ...] = ()  # what the fault-reset call reads


def view_name(name: str, depth: int) -> str:
    if depth == 0:
        return name
    return f"prev_{name}" if depth == 1 else f"prev{depth}_{name}"


@dataclass
class Views:
    """The variables through which one POU reads (name, depth) values."""

    scope: Scope
    idents: dict[tuple[str, int], str] = field(default_factory=dict)

    def get(self, name: str, depth: int = 0) -> str:
        key = (name, depth)
        found = self.idents.get(key)
        if found is None:
            found = self.idents[key] = self.scope.take(view_name(name, depth))
        return found

    def name(self, name: str, depth: int = 0) -> m.Name:
        return m.Name(self.get(name, depth))


def convert(node: Node, resolve: Callable[[str, int], m.Expr]) -> m.Expr:
    """A project condition (and, or, not, names, prev) as a PLC expression."""
    if isinstance(node, Const):
        return m.BoolLit(node.value)
    if isinstance(node, Var):
        return resolve(node.name, node.depth)
    if isinstance(node, Not):
        return m.not_(convert(node.operand, resolve))
    if isinstance(node, And):
        return m.and_(*(convert(op, resolve) for op in node.operands))
    if isinstance(node, Or):
        return m.or_(*(convert(op, resolve) for op in node.operands))
    # Step times (X3.t) are for the control law only; the loader keeps them out of the
    # timers, observers, constraints, diagnosers and monitors the export covers.
    raise TypeError(f"not exportable in a safety expression: {node!r}")


@dataclass
class Durations:
    """Durations as TIME literals; anything TIME cannot hold exactly is an error."""

    problems: list[Diagnostic] = field(default_factory=list)

    def time(self, us: int, pos: SourcePos, what: str) -> m.TimeLit:
        if us % 1000:
            self.problems.append(Diagnostic(
                pos, f"{what} is {us} us: a PLC TIME counts whole milliseconds",
                "a duration in whole milliseconds for the export"))
        elif us // 1000 >= TMAX_MS:
            self.problems.append(Diagnostic(
                pos, f"{what} is longer than the {TMAX_MS // 86_400_000} days the exported "
                "timers can measure", "a shorter duration"))
        return m.TimeLit(us // 1000)

    def raise_if_any(self) -> None:
        if self.problems:
            raise ProjectError(self.problems, [])
