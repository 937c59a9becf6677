"""The safety program: one PLC cycle in the engine's order (hmi/engine/scan.py).

    first cycle: the history is the engine's initial image
    2 Memory   3-4 each Diag_<D>   5 Control   6 Filter   7 outputs
    8 each Mon_<task>   a fault reset (after the scan)   the history shifts

The declared stages' blocks (2-6 and 8, and each added stage's, hmi.export.stage_blocks) are
called at their part of the scan as their StageCall says; the scan's time and the output
scan are the program's own.

The program holds the history its function blocks read: `prev_x` is x at the previous scan,
`prev2_x` two scans back. Each FB input standing for (x, depth) is wired to the value it
means at that point of the cycle; a diagnoser reads outputs one scan further back (what the
plant received), and its reset call reads the scan just ended (see :func:`build_program`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from hmi.export import model as m
from hmi.export import source
from hmi.export.image import Globals
from hmi.export.names import Scope
from hmi.export.stage_blocks import StageCall
from hmi.export.views import TMAX_MS, Block, Durations, view_name
from hmi.program import order
from hmi.project.model import Project


@dataclass
class Blocks:
    """The function blocks the program calls."""

    # each exported stage's blocks (hmi.export.stage_blocks) by the part they are called at,
    # in the stages' order
    stages: list[tuple[str, list[StageCall]]] = field(default_factory=list)
    # the added stages' places (part, after): hmi.program.order.placed
    places: list[tuple[str, str]] = field(default_factory=list)

    def of(self, part: str) -> list[Block]:
        """The blocks called at `part`."""
        return [c.block for at, calls in self.stages if at == part for c in calls]


@dataclass
class _Program:
    g: Globals
    scope: Scope  # the program's own names, below the globals
    instances: dict[str, str] = field(default_factory=dict)
    history: dict[tuple[str, int], str] = field(default_factory=dict)

    def instance(self, key: str) -> str:
        if key not in self.instances:
            self.instances[key] = self.scope.take(key)
        return self.instances[key]

    def value(self, name: str, depth: int) -> m.Expr:
        """`name` as it stands `depth` scans back, at this point of the cycle."""
        if depth == 0:
            return self.g.name(name)
        for d in range(1, depth + 1):
            if (name, d) not in self.history:
                self.history[(name, d)] = self.scope.take(view_name(name, d))
        return m.Name(self.history[(name, depth)])

    def wire(self, block: Block, shift: Callable[[str, int], m.Expr] | None = None
             ) -> list[tuple[str, m.Expr]]:
        return [(ident, self.value(name, depth) if shift is None else shift(name, depth))
                for (name, depth), ident in block.inputs.items()]


def build_program(project: Project, name: str, g: Globals, b: Blocks,
                  durations: Durations) -> tuple[m.Pou, dict[str, str]]:
    p = _Program(g, g.scope.child())
    outputs = {v.name for v in source.outputs(project)}
    clock, now = p.scope.take("Clock"), p.scope.take("Now")

    def inputs() -> list[m.Stmt]:
        # (the register bits are read first, before the first scan's history: g.read)
        return [m.Comment("the scan's time: the program's clock, since its first scan"),
                m.FbCall(clock, (("IN", m.TRUE), ("PT", m.TimeLit(TMAX_MS)))),
                m.Assign(m.Name(now), m.Member(m.Name(clock), "ET"))]

    # The scan's parts in the engine's order (hmi.program.order, with the added stages'
    # places), each the blocks that run it: the declared stages' (hmi.export.stage_blocks)
    # and the program's own.
    parts: dict[str, Callable[[], list[m.Stmt]]] = {
        order.INPUTS: inputs, order.OUTPUTS: lambda: list(g.write)}
    calls: dict[str, list[StageCall]] = {}
    for at, stage in b.stages:
        calls.setdefault(at, []).extend(stage)
    body: list[m.Stmt] = []
    for part in order.placed(order.SCAN, b.places):
        if part in parts:
            body += parts[part]()
        for call in calls.get(part, ()):
            body += _call(p, call, now, outputs)
    body.append(m.Comment("A fault reset, after the scan (the engine resets between scans)"))
    body.append(m.if_(g.name("FaultReset"), *_reset(project, p, b)))
    body.append(m.Comment("The history: this scan's values become the previous ones"))
    for (n, depth), ident in sorted(p.history.items(), key=lambda kv: (kv[0][0], -kv[0][1])):
        newer = g.name(n) if depth == 1 else m.Name(p.history[(n, depth - 1)])
        body.append(m.Assign(m.Name(ident), newer))
    started = p.scope.take("Started")
    first: list[m.Stmt] = [
        m.Comment("The first scan: the history is the initial image (inputs as read, "
                  "outputs safe, observers initial, the rest 0)"),
        m.if_(m.not_(m.Name(started)),
              *(m.Assign(m.Name(ident), g.initial.get(n, m.FALSE))
                for (n, _), ident in p.history.items()),
              m.Assign(m.Name(started), m.TRUE))]

    types = {c.key: c.block.pou.name for _, stage in b.stages for c in stage}
    locals_ = [m.Var(started, m.BOOL), m.Var(clock, m.Derived("TON")),
               m.Var(now, m.TIME, comment="the scan's time")]
    locals_ += [m.Var(ident, m.Derived(types[key])) for key, ident in p.instances.items()]
    locals_ += [m.Var(ident, m.BOOL, comment=f"{n}, {d} scan{'s' if d > 1 else ''} back")
                for (n, d), ident in p.history.items()]
    pou = m.Pou(name, "program", (
        m.VarBlock("external", tuple(m.Var(v.name, v.type) for v in g.all)),
        m.VarBlock("local", tuple(locals_))),
        tuple(g.read + first + body),
        "The cell's cycle, in the engine's order. Call it once per PLC cycle from the task.")
    return pou, dict(p.instances)


def _call(p: _Program, call: StageCall, now: str, outputs: set[str]) -> list[m.Stmt]:
    """A declared stage's block called (hmi.export.stage_blocks.StageCall): the scan's
    time, its fixed ports, what it reads wired, its outputs and results to the globals."""
    block = call.block
    inst = p.instance(call.key)
    shift = (lambda n, d: p.value(n, d + (n in outputs))) if call.outputs_back else None
    return [*((m.Comment(call.comment),) if call.comment is not None else ()),
            m.FbCall(inst, (*(((block.ports["Now"], m.Name(now)),) if call.now else ()),
                            *((block.ports[port], value) for port, value in call.consts),
                            *((block.ports[port], p.g.name(key)) for port, key in call.reads),
                            *p.wire(block, shift))),
            *(m.Assign(p.g.name(n), m.Member(m.Name(inst), out))
              for n, out in block.outputs.items()),
            *(m.Assign(p.g.name(key), m.Member(m.Name(inst), block.ports[port]))
              for key, port in call.results)]


def _reset(project: Project, p: _Program, b: Blocks) -> list[m.Stmt]:
    outputs = {v.name for v in source.outputs(project)}
    stmts: list[m.Stmt] = [m.Assign(p.g.name("FaultReset"), m.FALSE)]

    # The engine resets between scans, on the image of the scan just ended, which is also
    # the newest history entry: a read at depth d (outputs one deeper) is the value d - 1
    # scans back, at least this scan's.
    def back(n: str, d: int) -> m.Expr:
        return p.value(n, max(d + (n in outputs) - 1, 0))

    # the latch first (as Engine.fault_reset releases it before the stages), then each stage
    # in order
    resets = sorted((c for _, stage in b.stages for c in stage if c.resets),
                    key=lambda c: not c.latch)
    for call in resets:
        block = call.block
        stmts.append(m.FbCall(p.instances[call.key], (
            (block.ports["Reset"], m.TRUE),
            *((block.inputs[key], back(*key)) for key in block.reset_reads))))
    return stmts
