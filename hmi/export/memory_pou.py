"""The memory stage as a function block: the project's timers and observers (scan step 2),
printed from the scan program.

The engine's stage (hmi.engine.stages.Memory) is lowered once into the scan program
(hmi.program.timers: TON and TOF; hmi.program.memories: observers); this prints those very
statements (hmi.export.program_st), timers first, then observers, each in declaration
order. A timer's state is the engine's: ``since`` (when IN rose for a TON, fell for a TOF;
a TIME with a BOOL saying "none") and ``q``, measured on the program's clock ``Now``. A
timer or observer read at the current scan by one declared before it is read with the
value it has so far this scan, i.e. its previous one, exactly as the engine's image does:
the FB's output variables keep their value between calls.
"""

from __future__ import annotations

from hmi.engine.layout import Layout
from hmi.engine.stages import Memory
from hmi.export import model as m
from hmi.export import source
from hmi.export.names import Scope
from hmi.export.program_st import BOOL, NTIME, TIME, NotPrintable, Place, Places, StPrinter
from hmi.export.views import Block, Durations, Views
from hmi.project.model import Project


def build_memory(memory: Memory, project: Project, layout: Layout, pou_name: str,
                 scope: Scope, durations: Durations) -> Block | None:
    timers, observers = source.timers(project), source.observers(project)
    if not timers and not observers:
        return None
    for t in timers:  # (each reported at its timer; the printer then finds them whole)
        durations.time(t.preset_us, t.pos, f"the preset of timer {t.name!r}")
    sc = scope.child()
    now = sc.take("Now")
    outputs = {name: sc.take(name) for name in [t.name for t in timers]
               + [o.name for o in observers]}
    views = Views(sc)
    places = Places(slot=lambda index: _slot(layout, index, outputs, views),
                    read=lambda name, depth: (m.Name(outputs[name])
                                              if depth == 0 and name in outputs
                                              else views.name(name, depth)),
                    step_time=_no_step_time, now=m.Name(now))
    state: list[m.Var] = []
    for runtime, _, _ in memory.timers:
        since, none, q = (sc.take(f"{runtime.name}_{part}") for part in ("since", "none", "q"))
        places.cell(runtime, "since", Place(since, NTIME, none))
        places.cell(runtime, "q", Place(q, BOOL))
        state += [m.Var(since, m.TIME, comment=f"{runtime.name}: when IN "
                        + ("rose" if runtime.kind == "TON" else "fell")),
                  m.Var(none, m.BOOL, m.TRUE if runtime.since is None else None,
                        comment=f"{runtime.name}: no such time"),
                  m.Var(q, m.BOOL, m.TRUE if runtime.q else None)]
    printer = StPrinter(places, sc, Durations(), project.pos, "the memory")
    body = printer.program(memory.program)
    initial = {o.name: o.initial for o in observers}
    described = {t.name: t.description for t in timers}
    described.update((o.name, o.description) for o in observers)
    blocks = (
        m.VarBlock("input", (m.Var(now, m.TIME, comment="the program's clock"),
                             *(m.Var(ident, m.BOOL) for ident in views.idents.values()))),
        m.VarBlock("output", tuple(
            m.Var(ident, m.BOOL, m.BoolLit(True) if initial.get(name) else None,
                  comment=described.get(name, ""))
            for name, ident in outputs.items())),
        m.VarBlock("local", (*state, *printer.locals)),
    )
    comment = ("Scan step 2, the memory: the project's timers (TON/TOF) and observers, "
               "in declaration order, as the engine's scan program runs them. Inputs: the "
               "values they read; prev_x is x at the previous scan.")
    return Block(m.Pou(pou_name, "functionBlock", blocks, tuple(body), comment),
                 dict(views.idents), outputs, {"Now": now})


def _slot(layout: Layout, index: int, outputs: dict[str, str], views: Views) -> Place:
    name = layout.names[index]
    if name in outputs:
        return Place(outputs[name], BOOL)
    if layout.kinds[index] == "step_time":
        return Place(views.get(name), TIME)
    return Place(views.get(name), BOOL)


def _no_step_time(step: str) -> m.Expr:
    raise NotPrintable(f"a timer or observer reads {step}.t (the loader keeps step times to "
                       "the control law)")
