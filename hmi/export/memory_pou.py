"""The memory stage as a function block: the project's timers and observers (scan step 2).

As in the engine (hmi/engine/scan.py): timers first, then observers, each in declaration
order. A timer or observer read at the current scan by one declared before it is read with
the value it has so far this scan, i.e. its previous one, exactly as the engine's image does;
that is what an FB's output variables, which keep their value between calls, give for free.
"""

from __future__ import annotations

from hmi.export import model as m
from hmi.export import source
from hmi.export.names import Scope
from hmi.export.views import Block, Durations, Views, convert
from hmi.project.model import Project


def build_memory(project: Project, pou_name: str, scope: Scope, durations: Durations
                 ) -> Block | None:
    timers, observers = source.timers(project), source.observers(project)
    if not timers and not observers:
        return None
    sc = scope.child()
    own = {t.name for t in timers} | {o.name for o in observers}
    outputs = {name: sc.take(name) for name in [t.name for t in timers]
               + [o.name for o in observers]}
    instances = {t.name: sc.take(f"T_{t.name}") for t in timers}
    views = Views(sc)

    def resolve(name: str, depth: int) -> m.Expr:
        if depth == 0 and name in own:
            return m.Name(outputs[name])
        return views.name(name, depth)

    body: list[m.Stmt] = []
    for t in timers:
        preset = durations.time(t.preset_us, t.pos, f"the preset of timer {t.name!r}")
        body.append(m.Comment(f"{t.name}: {t.kind}, IN = {t.input}"))
        body.append(m.FbCall(instances[t.name], (("IN", convert(t.input.root, resolve)),
                                                 ("PT", preset))))
        body.append(m.Assign(m.Name(outputs[t.name]), m.Member(m.Name(instances[t.name]),
                                                                "Q")))
    for o in observers:
        target = m.Name(outputs[o.name])
        if o.expr is not None:
            body.append(m.Comment(f"{o.name} = {o.expr}"))
            body.append(m.Assign(target, convert(o.expr.root, resolve)))
        else:
            assert o.set is not None and o.reset is not None
            body.append(m.Comment(f"{o.name}: set {o.set}, reset {o.reset} (reset wins)"))
            body.append(m.Assign(target, m.and_(m.not_(convert(o.reset.root, resolve)),
                                                m.or_(convert(o.set.root, resolve), target))))
    initial = {o.name: o.initial for o in observers}
    blocks = (
        m.VarBlock("input", tuple(m.Var(ident, m.BOOL) for ident in views.idents.values())),
        m.VarBlock("output", tuple(
            m.Var(ident, m.BOOL, m.BoolLit(True) if initial.get(name) else None,
                  comment=_what(project, name))
            for name, ident in outputs.items())),
        m.VarBlock("local", tuple(
            m.Var(instances[t.name], m.Derived(t.kind)) for t in timers)),
    )
    comment = ("Scan step 2, the memory: the project's timers (TON/TOF) and observers, "
               "in declaration order. Inputs: the values they read; prev_x is x at the "
               "previous scan.")
    return Block(m.Pou(pou_name, "functionBlock", blocks, tuple(body), comment),
                 dict(views.idents), outputs)


def _what(project: Project, name: str) -> str:
    for item in (*source.timers(project), *source.observers(project)):
        if item.name == name:
            return item.description
    return ""
