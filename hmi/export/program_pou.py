"""The safety program: one PLC cycle in the engine's order (hmi/engine/scan.py).

    first cycle: the history is the engine's initial image
    2 Memory   3-4 each Diag_<D>   5 Control   6 Filter   7 outputs
    8 each Mon_<task>   a fault reset (after the scan)   the history shifts

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
from hmi.export.diagnoser_pou import ftc_mode
from hmi.export.image import Globals
from hmi.export.names import Scope
from hmi.export.views import TMAX_MS, Block, Durations, view_name
from hmi.program import order
from hmi.project.model import Project


@dataclass
class Blocks:
    """The function blocks the program calls."""

    memory: Block | None
    diagnosers: list[Block]
    filter: Block
    control: Block
    monitors: list[Block]
    # each added stage's block (hmi.export.stage_blocks) with its PLACE (part, after)
    added: list[tuple[tuple[str, str], Block]] = field(default_factory=list)


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
    specs = source.diagnosers(project)
    clock, now = p.scope.take("Clock"), p.scope.take("Now")

    def inputs() -> list[m.Stmt]:
        # (the register bits are read first, before the first scan's history: g.read)
        return [m.Comment("the scan's time: the program's clock, since its first scan"),
                m.FbCall(clock, (("IN", m.TRUE), ("PT", m.TimeLit(TMAX_MS)))),
                m.Assign(m.Name(now), m.Member(m.Name(clock), "ET"))]

    def memory() -> list[m.Stmt]:
        if b.memory is None:
            return []
        inst = p.instance("Memory")
        return [m.Comment("2. Memory: timers and observers"),
                m.FbCall(inst, ((b.memory.ports["Now"], m.Name(now)), *p.wire(b.memory))),
                *(m.Assign(g.name(n), m.Member(m.Name(inst), out))
                  for n, out in b.memory.outputs.items())]

    def diagnosers() -> list[m.Stmt]:  # (each with its reconstruction)
        out: list[m.Stmt] = []
        for spec, block in zip(specs, b.diagnosers, strict=True):
            inst = p.instance(f"Diag_{spec.name}")
            out.append(m.Comment(f"3-4. Diagnoser {spec.name}: an output is read as written "
                                 "at the previous scan"))
            out.append(m.FbCall(inst, (
                (block.ports["Now"], m.Name(now)), (block.ports["Reset"], m.FALSE),
                (block.ports["Mode"], g.name("DiagnosisMode")),
                *p.wire(block, lambda n, d: p.value(n, d + (n in outputs))))))
            out += [m.Assign(g.name(n), m.Member(m.Name(inst), o))
                    for n, o in block.outputs.items()]
        return out

    def law() -> list[m.Stmt]:  # (with the step times: nothing before reads them)
        ctl = p.instance("Control")
        return [m.Comment("5. The functional control writes the FOV_ variables"),
                m.FbCall(ctl, ((b.control.ports["Now"], m.Name(now)), *p.wire(b.control)))]

    def filter_() -> list[m.Stmt]:
        filt = b.filter
        finst = p.instance("Filter")
        return [
            m.Comment("6. The safety filter"),
            m.FbCall(finst, (
                (filt.ports["Reset"], m.FALSE), (filt.ports["Policy"], g.name("FilterPolicy")),
                (filt.ports["Ftc"], ftc_mode(g.name("DiagnosisMode"))),
                *((filt.ports[f"FOV_{v.name}"], g.name(f"FOV_{v.name}"))
                  for v in source.outputs(project)),
                *p.wire(filt))),
            *(m.Assign(g.name(v.name), m.Member(m.Name(finst), filt.outputs[v.name]))
              for v in source.outputs(project)),
            *(m.Assign(g.name(key), m.Member(m.Name(finst), filt.ports[port]))
              for key, port in (("Violations", "Violations"), ("FilterLatched", "Latched"),
                                ("FilterFallback", "Fallback")))]

    def monitors() -> list[m.Stmt]:
        calls = _monitors(project, p, b, now)
        if not calls:
            return []
        return [m.Comment("7. The output scan (the PLC writes the outputs after the cycle); "
                          "8. the stopwatch monitors, on the I/O of this scan"), *calls]

    # The scan's parts in the engine's order (hmi.program.order), each the blocks that run
    # it; the recovery procedures are not exported (no recovery mode on the PLC).
    parts = {order.INPUTS: inputs, order.MEMORY: memory, order.DIAGNOSERS: diagnosers,
             order.LAW: law, order.FILTER: filter_, order.OUTPUTS: lambda: list(g.write),
             order.MONITORS: monitors}
    parts.update((part, _added(p, part, block, now)) for (part, _), block in b.added)
    body: list[m.Stmt] = []
    for part in order.placed(order.SCAN, [place for place, _ in b.added]):
        if part in parts:
            body += parts[part]()
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

    types = {"Memory": b.memory.pou.name if b.memory else "", "Control": b.control.pou.name,
             "Filter": b.filter.pou.name}
    types.update({f"Diag_{s.name}": blk.pou.name for s, blk in zip(specs, b.diagnosers,
                                                                   strict=True)})
    types.update({f"Mon_{t.name}": blk.pou.name for t, blk in zip(source.monitors(project),
                                                                  b.monitors, strict=True)})
    types.update({f"Stage_{part}": blk.pou.name for (part, _), blk in b.added})
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


def _added(p: _Program, part: str, block: Block, now: str) -> Callable[[], list[m.Stmt]]:
    """An added stage's call (hmi.engine.program_stages): its block with the scan's time
    and what it reads, its outputs to the globals."""
    def call() -> list[m.Stmt]:
        inst = p.instance(f"Stage_{part}")
        clock = ((block.ports["Now"], m.Name(now)),) if "Now" in block.ports else ()
        return [m.Comment(f"The added stage {part} ({block.pou.name})"),
                m.FbCall(inst, (*clock, *p.wire(block))),
                *(m.Assign(p.g.name(n), m.Member(m.Name(inst), out))
                  for n, out in block.outputs.items())]
    return call


def _monitors(project: Project, p: _Program, b: Blocks, now: str) -> list[m.Stmt]:
    out: list[m.Stmt] = []
    for task, block in zip(source.monitors(project), b.monitors, strict=True):
        inst = p.instance(f"Mon_{task.name}")
        out.append(m.FbCall(inst, ((block.ports["Now"], m.Name(now)),
                                   (block.ports["Reset"], m.FALSE), *p.wire(block))))
        out.append(m.Assign(p.g.name(task.label), m.Member(m.Name(inst), block.ports["Fault"])))
    return out


def _reset(project: Project, p: _Program, b: Blocks) -> list[m.Stmt]:
    outputs = {v.name for v in source.outputs(project)}
    stmts: list[m.Stmt] = [m.Assign(p.g.name("FaultReset"), m.FALSE),
                           m.FbCall(p.instances["Filter"], ((b.filter.ports["Reset"], m.TRUE),))]

    # The engine resets between scans, on the image of the scan just ended, which is also
    # the newest history entry: a read at depth d (outputs one deeper) is the value d - 1
    # scans back, at least this scan's.
    def back(n: str, d: int) -> m.Expr:
        return p.value(n, max(d + (n in outputs) - 1, 0))

    for spec, block in zip(source.diagnosers(project), b.diagnosers, strict=True):
        stmts.append(m.FbCall(p.instances[f"Diag_{spec.name}"], (
            (block.ports["Reset"], m.TRUE),
            *((block.inputs[key], back(*key)) for key in block.reset_reads))))
    for task, block in zip(source.monitors(project), b.monitors, strict=True):
        stmts.append(m.FbCall(p.instances[f"Mon_{task.name}"],
                              ((block.ports["Reset"], m.TRUE),)))
    return stmts
