"""The stopwatch monitor of one interruptible task (002) as a function block, printed from
the scan program.

The engine's monitor stage (hmi.engine.monitors.MonitorStage) lowers each task's automaton
once into the scan program (hmi.program.monitors: the stopwatches x and y, the location,
the verdicts of Property 1); this prints that task's statements (hmi.export.program_st), its
conditions (start, end, interruption) read on the values of this scan, its window as TIME
constants, with the ST versions of the two handlers they call: ``detect`` (the attempt's
fault: counted, and latched with its evidence unless a fault is latched already) and the
plain watchdog's ``trip`` (it only disarms: the watchdog is the engine's yardstick, not
exported). The automaton's state is the engine's: the phase (0 waiting, 1 executing,
2 interrupted), the stopwatches, the time of the last scan, the attempt, its start and its
fault (a TIME with a BOOL "none": when the fault was found).

A fault reset is a call of its own (``Reset := TRUE``, after the scan): the label is
released unless the attempt that failed still runs (TaskAutomaton.reset).
"""

from __future__ import annotations

from typing import Any

from hmi.engine.layout import Layout
from hmi.engine.monitors import MonitorStage
from hmi.engine.stopwatch import Phase
from hmi.export import model as m
from hmi.export.names import Scope
from hmi.export.program_st import (
    BOOL,
    DINT,
    INT,
    NTIME,
    TIME,
    Handler,
    NotPrintable,
    Place,
    Places,
    StPrinter,
)
from hmi.export.views import Block, Durations, Views
from hmi.project.model import TaskMonitor

WAITING, EXECUTING, INTERRUPTED, FAULTY = 0, 1, 2, 3
PHASES = {Phase.IDLE: WAITING, Phase.RUNNING: EXECUTING, Phase.SUSPENDED: INTERRUPTED}
PORTS = ("Now", "Reset", "Location", "X", "Y", "Fault", "Rule", "FaultX", "FaultY", "Attempt",
         "Faults", "Completed", "Phase", "LastUs", "AttemptStart", "AttemptFault",
         "AttemptFaultNone", "Armed")


def build_monitor(stage: MonitorStage, k: int, spec: TaskMonitor, layout: Layout,
                  pou_name: str, scope: Scope, durations: Durations) -> Block:
    """Task `k` of `stage` (its `spec`) as FB `pou_name`: its inputs (Now, the values its
    conditions read, by (name, depth)) for the program to wire."""
    automaton = stage.automata[k]
    sc = scope.child()
    t = {key: sc.take(key) for key in PORTS}

    def v(key: str) -> m.Name:
        return m.Name(t[key])

    views = Views(sc)

    def slot(index: int) -> Place:
        if layout.kinds[index] == "step_time":
            raise NotPrintable(f"monitor {spec.name!r} reads a step time")
        return Place(views.get(layout.names[index]), BOOL)

    places = Places(slot=slot, read=lambda name, depth: views.name(name, depth),
                    step_time=lambda step: _no_step_time(spec, step), now=v("Now"))
    for phase, code in PHASES.items():
        places.code(phase, code)
    for attr, key, kind in (("phase", "Phase", INT), ("x_us", "X", TIME), ("y_us", "Y", TIME),
                            ("last_us", "LastUs", TIME), ("attempt", "Attempt", DINT),
                            ("attempt_start_us", "AttemptStart", TIME),
                            ("completed", "Completed", DINT)):
        places.cell(automaton, attr, Place(t[key], kind))
    places.cell(automaton, "attempt_fault", Place(t["AttemptFault"], NTIME,
                                                  t["AttemptFaultNone"]))
    places.cell(automaton, "changes", None)  # (the snapshot's marks: not kept)
    places.cell(stage.dirty, k, None)
    places.cell(automaton.watchdog, "_armed", Place(t["Armed"], BOOL))
    places.handler(automaton, "detect", Handler(lambda printer, args: _detect(v, args)))
    places.handler(automaton.watchdog, "trip",
                   Handler(lambda printer, args: [m.Assign(v("Armed"), m.FALSE)]))
    printer = StPrinter(places, sc, durations, spec.pos, f"the window of monitor {spec.name!r}")
    step = printer.program(stage.programs[k])
    reset = m.if_(m.and_(v("Fault"), m.not_(m.and_(m.Binary("<>", v("Phase"),
                                                             m.IntLit(WAITING)),
                                                    m.not_(v("AttemptFaultNone"))))),
                  m.Assign(v("Fault"), m.FALSE), m.Assign(v("Rule"), m.IntLit(0)))
    body = (
        m.If(((v("Reset"), (m.Comment("fault reset: released unless the attempt that failed "
                                      "is still running"), reset)),), tuple(step)),
        m.If(((v("Fault"), (m.Assign(v("Location"), m.IntLit(FAULTY)),)),),
             (m.Assign(v("Location"), v("Phase")),)),
    )
    blocks = (
        m.VarBlock("input", (
            m.Var(t["Now"], m.TIME, comment="the program's clock"),
            m.Var(t["Reset"], m.BOOL, comment="TRUE: a fault reset (a call of its own)"),
            *(m.Var(ident, m.BOOL) for ident in views.idents.values()))),
        m.VarBlock("output", (
            m.Var(t["Location"], m.INT,
                  comment="0 waiting (l1), 1 executing (l2), 2 interrupted (l3), 3 faulty"),
            m.Var(t["X"], m.TIME, comment="time since the start"),
            m.Var(t["Y"], m.TIME, comment="effective work"),
            m.Var(t["Fault"], m.BOOL, comment="the fault label, latched until a reset"),
            m.Var(t["Rule"], m.INT, comment="1 cannot_finish, 2 deadline, 3 overrun, "
                  "4 late_end, 5 too_fast"),
            m.Var(t["FaultX"], m.TIME), m.Var(t["FaultY"], m.TIME),
            m.Var(t["Attempt"], m.DINT), m.Var(t["Faults"], m.DINT),
            m.Var(t["Completed"], m.DINT, comment="attempts ended in time"))),
        m.VarBlock("local", (
            m.Var(t["Phase"], m.INT, comment="the task as observed: 0, 1, 2"),
            m.Var(t["LastUs"], m.TIME, comment="the time of the last scan the task ran"),
            m.Var(t["AttemptStart"], m.TIME),
            m.Var(t["AttemptFault"], m.TIME, comment="when the attempt's fault was found"),
            m.Var(t["AttemptFaultNone"], m.BOOL, m.TRUE, comment="the attempt has no fault"),
            m.Var(t["Armed"], m.BOOL, comment="the plain watchdog (the engine's yardstick)"),
            *printer.locals)),
    )
    comment = (f"Stopwatch monitor of task {spec.name!r} (002), window alpha "
               f"{spec.alpha_us // 1000} ms, beta {spec.beta_us // 1000} ms, gamma "
               f"{spec.gamma_us // 1000} ms, as the engine's scan program runs it: the "
               "fault as soon as the task can no longer end inside [alpha, gamma) with y in "
               "[alpha, beta].")
    pou = m.Pou(pou_name, "functionBlock", blocks, body, comment)
    return Block(pou, dict(views.idents), {}, {key: t[key] for key in ("Now", "Reset",
                                                                      "Fault")})


def _detect(v: Any, args: tuple[Any, ...]) -> list[m.Stmt]:
    """TaskAutomaton.detect in ST: the attempt's fault, counted; latched with its evidence
    (the rule, x and y) unless a fault is latched already."""
    verdict, now, _scan = args
    return [m.Assign(v("AttemptFault"), now), m.Assign(v("AttemptFaultNone"), m.FALSE),
            m.Assign(v("Faults"), m.Binary("+", v("Faults"), m.IntLit(1))),
            m.if_(m.not_(v("Fault")), m.Assign(v("Fault"), m.TRUE),
                  m.Assign(v("Rule"), verdict), m.Assign(v("FaultX"), v("X")),
                  m.Assign(v("FaultY"), v("Y")))]


def _no_step_time(spec: TaskMonitor, step: str) -> m.Expr:
    raise NotPrintable(f"monitor {spec.name!r} reads {step}.t (the loader keeps step times "
                       "to the control law)")
