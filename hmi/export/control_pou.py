"""The functional control (scan step 5) as a function block, printed from the scan program.

The engine's control law (hmi.engine.control.ControlRuntime: the GRAFCET's step times, its
evolution and continuous actions, then the equations) is lowered once into the scan
program (hmi.program.grafcet, hmi.program.memories); this prints those very statements
(hmi.export.program_st), with the ST version of the one handler they call, the GRAFCET's
firing (:func:`_fire`, what GrafcetRuntime.fire does), so a PLC runs the law the filter was
validated with.

Where the law's values live:

* an output O is the program's FOV_O: it first takes the order written at the previous
  scan (the engine's image holds it until the law writes it: an output no action drives
  keeps it), then the law's continuous and stored actions and equations write it;
* the steps X<n>, their activity times (TIME) and activation times, and the memories are
  this block's own variables (nothing else in the safety layer reads them), initialised as
  the engine's first scan resets the GRAFCET (the initial steps active since that scan, their
  stored actions done);
* inputs, timers, observers, flags and filtered sensors are the globals, read as stage 5
  reads them; a value one or more scans back is an input the program wires (prev_x), or,
  for the block's own values, a history kept here;
* ``Now``, the program's clock, is an input.
"""

from __future__ import annotations

from typing import Any

from hmi.engine.control import ControlRuntime
from hmi.engine.grafcet import GrafcetRuntime
from hmi.engine.layout import Layout
from hmi.export import model as m
from hmi.export.image import Globals
from hmi.export.names import Scope
from hmi.export.program_st import BOOL, TIME, Handler, NotPrintable, Place, Places, StPrinter
from hmi.export.views import Block, Durations, view_name
from hmi.project.model import ControlLaw, Project

OWN = ("memory", "step", "step_time")  # the image's kinds this block keeps itself


def build_control(runtime: ControlRuntime, project: Project, layout: Layout, g: Globals,
                  pou_name: str, scope: Scope, durations: Durations) -> Block:
    """`runtime`'s law as FB `pou_name`: its inputs (Now and the values read back in time,
    by (name, depth)) for the program to wire."""
    law = runtime.law
    sc = scope.child()
    now = sc.take("Now")
    started = sc.take("Started")
    own: dict[str, str] = {}  # image name -> this block's variable
    own_initial: dict[str, m.Expr] = {}
    safe = {v.name: v.safe for v in project.memories}
    grafcet = runtime.grafcet
    initial_steps = set(grafcet.initial) if grafcet is not None else set()
    for name, kind in zip(layout.names, layout.kinds, strict=True):
        if kind == "memory":
            own[name] = sc.take(name)
            own_initial[name] = m.BoolLit(safe[name])
        elif kind == "step":
            own[name] = sc.take(name)
            own_initial[name] = m.BoolLit(name in initial_steps)
        elif kind == "step_time":
            own[name] = sc.take(name.replace(".t", "_t"))
    inputs: dict[tuple[str, int], str] = {}  # the program's values read here, by (name, depth)
    history: dict[tuple[str, int], str] = {}  # own values back in time
    externals: dict[str, None] = {}  # the globals this block reads or writes

    def global_(name: str) -> Place:
        ident = g.idents[name]
        externals[ident] = None
        return Place(ident, BOOL)

    def slot(index: int) -> Place:
        name, kind = layout.names[index], layout.kinds[index]
        if kind == "output":
            return global_(f"FOV_{name}")
        if kind in OWN:
            return Place(own[name], TIME if kind == "step_time" else BOOL)
        if name in g.idents:
            return global_(name)
        raise NotPrintable(f"the law reads {name!r}, which the export does not hold")

    def read(name: str, depth: int) -> m.Expr:
        if depth == 0:
            return slot(layout.slots[name]).expr
        if name in own:
            for d in range(1, depth + 1):
                if (name, d) not in history:
                    history[(name, d)] = sc.take(view_name(name, d))
            return m.Name(history[(name, depth)])
        key = (name, depth)
        if key not in inputs:
            inputs[key] = sc.take(view_name(name, depth))
        return m.Name(inputs[key])

    places = Places(slot=slot, read=read,
                    step_time=lambda step: m.Name(own[f"{step}.t"]), now=m.Name(now))
    since: dict[str, str] = {}
    if grafcet is not None:
        for k, step in enumerate(grafcet.names):
            since[step] = sc.take(f"{step}_since")
            places.cell(grafcet.since, k, Place(since[step], TIME))
        places.cell(grafcet, "fired", None)  # (what the snapshot shows: not kept)
        places.handler(grafcet, "fire", Handler(_fire(grafcet, slot, since)))
    printer = StPrinter(places, sc, durations, law.pos, f"control {law.name!r}")
    law_body = printer.program(runtime.times + runtime.program)

    body: list[m.Stmt] = [
        m.Comment("the image's outputs: the orders written at the previous scan, until the "
                  "law writes them"),
        *(m.Assign(slot(layout.slots[v.name]).expr, global_(v.name).expr)
          for v in project.outputs)]
    reset: list[m.Stmt] = [m.Assign(m.Name(started), m.TRUE)]
    if grafcet is not None:
        for step in grafcet.initial:
            reset.append(m.Assign(m.Name(since[step]), m.Name(now)))
            reset += _stored(grafcet, step, slot)
    reset += [m.Assign(m.Name(ident), m.Name(own[name]))
              for (name, _), ident in history.items()]
    body.append(m.Comment("the first scan: the GRAFCET in its initial steps, their stored "
                          "actions done"))
    body.append(m.if_(m.not_(m.Name(started)), *reset))
    body.append(m.Comment("the step times, the evolution, the continuous actions, the "
                          "equations: the engine's scan program"))
    body += law_body
    if history:
        body.append(m.Comment("this block's values back in time"))
        for (name, depth), ident in sorted(history.items(), key=lambda kv: (kv[0][0],
                                                                              -kv[0][1])):
            newer = own[name] if depth == 1 else history[(name, depth - 1)]
            body.append(m.Assign(m.Name(ident), m.Name(newer)))

    types = {v.name: v.type for v in g.vars}
    own_vars = [m.Var(own[name], m.TIME if kind == "step_time" else m.BOOL,
                      own_initial.get(name) if own_initial.get(name) != m.FALSE else None,
                      comment=_what(project, law, name, kind))
                for name, kind in zip(layout.names, layout.kinds, strict=True) if kind in OWN]
    blocks = (
        m.VarBlock("input", (m.Var(now, m.TIME, comment="the program's clock"),
                             *(m.Var(ident, m.BOOL) for ident in inputs.values()))),
        m.VarBlock("external", tuple(m.Var(ident, types[ident]) for ident in externals)),
        m.VarBlock("local", (
            m.Var(started, m.BOOL), *own_vars,
            *(m.Var(ident, m.TIME, comment=f"when {step} was activated")
              for step, ident in since.items()),
            *(m.Var(ident, m.BOOL) for ident in history.values()),
            *printer.locals)),
    )
    comment = (f"Scan step 5: the functional control, law {law.name!r}"
               + (f" ({law.description})" if law.description else "") + ".\n"
               "The engine's scan program for it: GRAFCET step times, evolution (all "
               "fireable transitions together), continuous actions, equations.\n"
               "It writes the program's outputs FOV_x; the filter decides what reaches the "
               "plant.")
    pou = m.Pou(pou_name, "functionBlock", blocks, tuple(body), comment)
    return Block(pou, dict(inputs), {}, {"Now": now})


def _stored(grafcet: GrafcetRuntime, step: str, slot: Any) -> list[m.Stmt]:
    return [m.Assign(slot(target).expr, m.BoolLit(value))
            for target, value in grafcet.stored.get(step, ())]


def _fire(grafcet: GrafcetRuntime, slot: Any, since: dict[str, str]) -> Any:
    """GrafcetRuntime.fire in ST: the transitions found fireable (one BOOL each) fire
    together: the steps upstream of one and downstream of none are deactivated (their time
    0), the steps downstream of one activated at `now` (their time restarts, rule 5) with
    their stored actions, in the order of their names as the runtime does."""

    def print_(printer: StPrinter, args: tuple[Any, ...]) -> list[m.Stmt]:
        flags, _image, now = args
        upstream: dict[str, list[m.Expr]] = {}
        downstream: dict[str, list[m.Expr]] = {}
        for k, (sources, targets) in enumerate(grafcet.transitions):
            if k not in flags:
                continue
            for s in sources:
                upstream.setdefault(s, []).append(m.Name(flags[k]))
            for s in targets:
                downstream.setdefault(s, []).append(m.Name(flags[k]))
        out: list[m.Stmt] = []
        for step in grafcet.names:
            if step not in upstream:
                continue
            test = m.or_(*upstream[step])
            if step in downstream:
                test = m.and_(test, m.not_(m.or_(*downstream[step])))
            out.append(m.if_(test, m.Assign(slot(grafcet.step_slots[step]).expr, m.FALSE),
                             m.Assign(slot(grafcet.time_slots[step]).expr, m.TimeLit(0))))
        for step in sorted(downstream):
            out.append(m.if_(m.or_(*downstream[step]),
                             m.Assign(slot(grafcet.step_slots[step]).expr, m.TRUE),
                             m.Assign(m.Name(since[step]), now),
                             m.Assign(slot(grafcet.time_slots[step]).expr, m.TimeLit(0)),
                             *_stored(grafcet, step, slot)))
        return out

    return print_


def _what(project: Project, law: ControlLaw, name: str, kind: str) -> str:
    if kind == "memory":
        return next((v.description for v in project.memories if v.name == name), "")
    if law.grafcet is not None:
        for step in law.grafcet.steps:
            if step.name == name:
                return f"step {step.number}: {step.description}"
            if f"{step.name}.t" == name:
                return f"how long step {step.number} has been active"
    return ""
