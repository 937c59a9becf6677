"""The local diagnosers (stage 3) and the reconstruction (stage 4), written once: the
lowering of each diagnoser's transitions into the scan program.

Semantics (hmi.engine.diagnoser's module docstring says why): at each scan a diagnoser's
current state's event transitions are tried in file order, the first whose condition holds
while the time in the state lies in its window [tmin, tmax) fires; if none fires, the
state's timeout fires once the time in the state reaches `after`. An output is read one
scan further back (:func:`shift_outputs`). A step longer than the gap (10 nominal periods),
or a scan skipped, is a gap in the observation (the stage's handler ``lost_sight``).

The state is the runtime's: the stage's ``dirty``, ``last_scan``, ``last_now`` and
``gap_us``; each diagnoser's ``current`` (its state's number, in declaration order) and
``since_us``. What the program hands to the runtime: ``begin(now, scan)`` (the first scan
a diagnoser sees), ``take(k, now, scan)`` (transition k of the specification fires: the
record the snapshot shows is built there), ``lost_sight(now, scan, delta)`` (a gap: True
when a state changed) and ``settle(image)`` (a state changed: the flags, the routes and
the mask follow).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from hmi.logic.expr import And, Compare, Node, Not, Or, Var
from hmi.program import ir
from hmi.program.ir import TRUE, Call, Cell, Const, Do, If, Local, Now, ScanNumber, Slot, Stmt, Test
from hmi.project.model import DiagnoserSpec

MODES = ("ftc", "observe", "off")


def shift_outputs(node: Node, outputs: frozenset[str]) -> Node:
    """The same condition with every output read one scan further back (a diagnoser
    observes the orders the plant received: those written at the previous scan)."""
    if isinstance(node, Var):
        return replace(node, depth=node.depth + 1) if node.name in outputs else node
    if isinstance(node, Not):
        return replace(node, operand=shift_outputs(node.operand, outputs))
    if isinstance(node, (And, Or)):
        return replace(node, operands=tuple(shift_outputs(op, outputs)
                                            for op in node.operands))
    if isinstance(node, Compare):
        return node
    return node


def lower_diagnosis(stage: Any, runtimes: list[tuple[Any, DiagnoserSpec]], mode: str,
                    outputs: frozenset[str], high_level: bool = False) -> tuple[Stmt, ...]:
    """Stage 3: the diagnosers of `stage` (each runtime with its specification) step once;
    then, with a High Level Diagnoser (`high_level`) and only while a decision it refines
    holds (the stage's ``hld_armed``), its handler ``refine(image, history)``; a state or a
    decision changed, the stage settles."""
    changed = Local("changed")
    settle = If(changed, (Do(Call(stage, "settle", (ir.TheImage(),))),))
    if mode == "off":  # the diagnosers do not run; the stage settles once (or after a reset)
        return (ir.Assign(changed, Cell(stage, "dirty")), settle)
    last, delta = Local("ls"), Local("delta")
    gap = Do(Call(stage, "lost_sight", (Now(), ScanNumber(), delta)))
    body: list[Stmt] = [
        ir.Assign(changed, Cell(stage, "dirty")),
        ir.Assign(last, Cell(stage, "last_scan")),
        If(ir.Not(ir.IsNone(last)), (
            ir.Assign(delta, ir.Sub(Now(), Cell(stage, "last_now"))),
            If(ir.Or((ir.Compare("!=", ScanNumber(), ir.Add(last, Const(1))),
                        ir.Compare(">", delta, Cell(stage, "gap_us")))),
               (If(gap.call, (ir.Assign(changed, TRUE),)),)))),
        ir.Assign(Cell(stage, "last_scan"), ScanNumber()),
        ir.Assign(Cell(stage, "last_now"), Now()),
    ]
    for runtime, spec in runtimes:
        body += lower_diagnoser(runtime, spec, outputs, changed)
    if high_level:
        body.append(If(ir.And((Cell(stage, "hld_armed"),
                               Call(stage, "refine", (ir.TheImage(), ir.TheHistory())))),
                       (ir.Assign(changed, TRUE),)))
    body.append(settle)
    return tuple(body)


def lower_diagnoser(runtime: Any, spec: DiagnoserSpec, outputs: frozenset[str],
                    changed: Local) -> tuple[Stmt, ...]:
    """One scan of one diagnoser: its current state's transitions in file order, the first
    that fires calls ``take``; `changed` set then."""
    index = {s.name: k for k, s in enumerate(spec.states)}
    since, t = Local("su"), Local("t")
    per_state: dict[int, list[tuple[ir.Value, tuple[Stmt, ...]]]] = {}
    timeouts: dict[int, tuple[ir.Value, tuple[Stmt, ...]]] = {}
    for k, tr in enumerate(spec.transitions):
        fire = (Do(Call(runtime, "take", (Const(k), Now(), ScanNumber()))),
                ir.Assign(changed, TRUE))
        source = index[tr.source]
        if tr.when is None:
            timeouts[source] = (ir.Compare(">=", t, Const(int(tr.after_us or 0))), fire)
            continue
        window: list[ir.Value] = []
        if tr.tmin_us:  # (the time in a state is never negative)
            window.append(ir.Compare(">=", t, Const(int(tr.tmin_us))))
        if tr.tmax_us is not None:
            window.append(ir.Compare("<", t, Const(int(tr.tmax_us))))
        test = ir.all_of(*window, Test(shift_outputs(tr.when.root, outputs)))
        per_state.setdefault(source, []).append((test, fire))
    cases = []
    for state in range(len(spec.states)):
        branches = per_state.get(state, [])
        if state in timeouts:
            branches = [*branches, timeouts[state]]
        if branches:
            cases.append((state, ir.if_chain(branches)))
    current = Local("c")
    return (
        ir.Assign(since, Cell(runtime, "since_us")),
        If(ir.IsNone(since), (Do(Call(runtime, "begin", (Now(), ScanNumber()))),
                           ir.Assign(since, Now()))),
        ir.Assign(t, ir.Sub(Now(), since)),
        ir.Assign(current, Cell(runtime, "current")),
        ir.Switch(current, tuple(cases)),
    )


def lower_reconstruction(sensors: list[tuple[int, int, int, int]], mode: str
                         ) -> tuple[Stmt, ...]:
    """Stage 4: each filtered sensor (filtered slot, sensor slot, estimate slot, flag slot)
    is the sensor, or its estimate while its partition's flag is set and the diagnosers
    drive the filter (ftc): ``x_filter = not def and x or def and x_hat`` (000 eq. 7-8)."""
    body: list[Stmt] = []
    for filtered, sensor, estimate, flag in sensors:
        if mode == "ftc":
            body.append(If(Slot(flag), (ir.Assign(Slot(filtered), Slot(estimate)),),
                           (ir.Assign(Slot(filtered), Slot(sensor)),)))
        else:
            body.append(ir.Assign(Slot(filtered), Slot(sensor)))
    return tuple(body)

