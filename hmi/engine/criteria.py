"""What each active GRAFCET step waits for: the criteria analysis of S7-GRAPH.

For each active step, each transition leaving it (none of them fired, or the step would no
longer be active): its receptivity as parsed (hmi.logic.expr's tree, printed back), the
current value of every variable it reads, the other upstream steps of a join that are not
active, and whether the receptivity holds on these values. Read from a snapshot alone (its
layout carries the project's GRAFCET, its values the image the scan left): nothing is
computed at a scan, only when a reader asks (the control panel, an explanation), so a quiet
scan pays nothing for it.

    X3 waits for B and e — B 0, e 1
    X3 waits for B and e, and X10 active — B 1, e 1
    X1 waits for X1.t ≥ 300ms — 0.12 s
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from hmi.logic.expr import (
    And,
    Compare,
    Const,
    Duration,
    Node,
    Not,
    Or,
    StepTime,
    Var,
    to_text,
    walk,
)
from hmi.project.model import Grafcet

Values = Callable[[str], Any]  # a name's current value (a snapshot's: Snapshot.value)


# How the comparisons read on a screen.
_SYMBOLS = ((" >= ", " ≥ "), (" <= ", " ≤ "), (" != ", " ≠ "))


@dataclass(frozen=True)
class Wait:
    """What active step `step` waits for through transition `transition` (its number)."""

    step: str
    transition: int
    description: str  # the transition's, as the project wrote it ("" if none)
    receptivity: str  # printed from its tree: "B and e", "X1.t ≥ 300ms"
    values: tuple[tuple[str, Any], ...]  # each variable it reads, in order: B, X1.t (us)
    joins: tuple[str, ...]  # the other upstream steps of the transition not active
    holds: bool | None  # the receptivity on these values; None: it reads past scans
    targets: tuple[str, ...] = ()  # the steps it leads to
    # For a receptivity that is a product of literals (B and not e), the literals false now,
    # as (name, the value it needs): what is missing for it to hold. () otherwise.
    missing: tuple[tuple[str, bool], ...] = ()

    @property
    def shown_values(self) -> str:
        """'B 0, e 1'; a step time in seconds, alone when it is the only variable read
        ('0.12 s')."""
        return values_text(self.values)

    @property
    def condition(self) -> str:
        """'B and e', and for a join 'B and e, and X10 active'."""
        if not self.joins:
            return self.receptivity
        return f"{self.receptivity}, and {' and '.join(self.joins)} active"

    @property
    def text(self) -> str:
        """'X3 waits for B and e — B 0, e 1'."""
        shown = self.shown_values
        return f"{self.step} waits for {self.condition}" + (f" — {shown}" if shown else "")


def values_text(values: Sequence[tuple[str, Any]]) -> str:
    if len(values) == 1 and values[0][0].endswith(".t"):
        return value_text(values[0][0], values[0][1])
    return ", ".join(f"{name} {value_text(name, value)}" for name, value in values)


def value_text(name: str, value: Any) -> str:
    if name.endswith(".t"):
        return f"{int(value) / 1_000_000:.2f} s"
    if isinstance(value, bool):
        return str(int(value))
    return str(value)


def receptivity_text(node: Node) -> str:
    text = to_text(node)
    for written, shown in _SYMBOLS:
        text = text.replace(written, shown)
    return text


def read_names(node: Node) -> tuple[str, ...]:
    """The variables a receptivity reads, each once, in the order written (a step time as
    `X1.t`; `prev(x)` as x: its value now is what can be shown)."""
    names: dict[str, None] = {}
    for n in walk(node):
        if isinstance(n, Var):
            names.setdefault(n.name)
        elif isinstance(n, StepTime):
            names.setdefault(f"{n.step}.t")
    return tuple(names)


def _missing(node: Node, read: Values) -> tuple[tuple[str, bool], ...]:
    """The literals of a product (`B and not e`) false on `read`, as (name, value needed);
    () for any other form (what it needs is then not one value per variable)."""
    operands = node.operands if isinstance(node, And) else (node,)
    literals = []
    for op in operands:
        positive = not isinstance(op, Not)
        var = op.operand if isinstance(op, Not) else op
        if not isinstance(var, Var) or var.depth:
            return ()
        literals.append((var.name, positive))
    return tuple((name, need) for name, need in literals if bool(read(name)) != need)


def _value(node: Node, read: Values) -> Any:
    """`node` on the values `read` (a name's value; a step time's in us); None when it reads
    a past scan (a snapshot holds only the present). Interpreted from the tree, never eval'ed."""
    if isinstance(node, Const):
        return node.value
    if isinstance(node, Var):
        return None if node.depth else bool(read(node.name))
    if isinstance(node, Not):
        inner = _value(node.operand, read)
        return None if inner is None else not inner
    if isinstance(node, And | Or):
        parts = [_value(op, read) for op in node.operands]
        if any(p is None for p in parts):
            return None
        return all(parts) if isinstance(node, And) else any(parts)
    if isinstance(node, StepTime):
        return int(read(f"{node.step}.t"))
    if isinstance(node, Duration):
        return node.us
    if isinstance(node, Compare):
        left, right = _value(node.left, read), _value(node.right, read)
        if left is None or right is None:
            return None
        return {"<": left < right, "<=": left <= right, ">": left > right,
                ">=": left >= right, "==": left == right, "!=": left != right}[node.op]
    raise TypeError(node)


def waits(grafcet: Grafcet | None, active: Sequence[str], read: Values
          ) -> tuple[Wait, ...]:
    """What each of the `active` steps waits for, `read` giving a name's current value (a
    snapshot's: Snapshot.waits)."""
    if grafcet is None or not active:
        return ()
    on = set(active)
    found = []
    for step in active:
        for tr in grafcet.transitions:
            if step not in tr.sources:
                continue
            node = tr.receptivity.root
            names = read_names(node)
            found.append(Wait(
                step, tr.number, tr.description, receptivity_text(node),
                tuple((name, read(name)) for name in names),
                tuple(s for s in tr.sources if s != step and s not in on),
                _value(node, read), tr.targets, _missing(node, read)))
    return tuple(found)
