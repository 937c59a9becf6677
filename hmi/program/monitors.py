"""The stopwatch automaton of one interruptible task (002), written once: its scan lowered
into the scan program. hmi.engine.stopwatch's module docstring states the rules and why.

At each scan, given the task's four observations (start, end, suspend, resume):

* waiting: a start begins an attempt (x = y = 0; interrupted at once if suspend holds);
* executing or interrupted: the stopwatches advance by the time since the last scan (y only
  while executing); an end judges the attempt (late_end: x >= gamma, overrun: y > beta,
  too_fast: y < alpha) and the task waits again; else suspend interrupts an executing task,
  resume resumes an interrupted one, and the running rules are checked (cannot_finish:
  y < alpha and x + (alpha - y) >= gamma; deadline: y >= alpha and x >= gamma; overrun:
  y > beta, or y == beta while executing);
* the plain watchdog beside it trips once x reaches gamma during an armed attempt;
* a verdict on an attempt that has none yet is a detection (the automaton's ``detect``
  handler builds its evidence and latches the label).

The state is the automaton's (``phase``, ``x_us``, ``y_us``, ``last_us``, ``attempt``,
``attempt_start_us``, ``attempt_fault``, ``completed``, ``changes``, its watchdog's
``_armed``); whatever changes beside the stopwatches also runs `mark` (the monitor stage
notes that the snapshot's state of the task must be taken again).
"""

from __future__ import annotations

from typing import Any

from hmi.program import ir
from hmi.program.ir import FALSE, TRUE, Assign, Call, Cell, Const, Do, If, Local, Now, Stmt

# The verdicts' numbers (0: none), in the order of hmi.engine.stopwatch.RULES.
VERDICTS = ("cannot_finish", "deadline", "overrun", "late_end", "too_fast")
CANNOT_FINISH, DEADLINE, OVERRUN, LATE_END, TOO_FAST = range(1, 6)


def lower_task(automaton: Any, window: tuple[int, int, int], phases: tuple[Any, Any, Any],
               start: ir.Value, end: ir.Value, suspend: ir.Value, resume: ir.Value,
               mark: tuple[Stmt, ...] = ()) -> tuple[Stmt, ...]:
    """One scan of `automaton` (window alpha, beta, gamma in µs; `phases` the objects of
    its waiting, executing and interrupted phases, compared by identity)."""
    alpha, beta, gamma = (Const(int(w)) for w in window)
    idle, running, suspended = (ir.Ref(p) for p in phases)
    a = automaton

    def cell(name: str) -> Cell:
        return Cell(a, name)

    def count(name: str) -> Assign:
        return Assign(cell(name), ir.Add(cell(name), Const(1)))

    phase, x, y, el, e, verdict = (Local(n) for n in ("p", "x", "y", "el", "e", "verdict"))
    watchdog = a.watchdog  # (one object for the automaton's life)
    armed = Cell(watchdog, "_armed")
    changed = (count("changes"), *mark)

    def is_(value: ir.Value, which: ir.Ref) -> ir.Value:
        return ir.Compare("is", value, which)

    begin = (
        Assign(cell("last_us"), Now()),
        Assign(cell("phase"), running),
        Assign(cell("x_us"), Const(0)),
        Assign(cell("y_us"), Const(0)),
        count("attempt"),
        Assign(cell("attempt_start_us"), Now()),
        Assign(cell("attempt_fault"), ir.NONE),
        Assign(armed, TRUE),
        If(suspend, (Assign(cell("phase"), suspended),)),
        # (the watchdog, observed at x = 0, cannot trip: gamma > beta >= 0)
        *changed,
    )
    judge_end = ir.if_chain([
        (ir.Compare(">=", x, gamma), (Assign(verdict, Const(LATE_END)),)),
        (ir.Compare(">", y, beta), (Assign(verdict, Const(OVERRUN)),)),
        (ir.Compare("<", y, alpha), (Assign(verdict, Const(TOO_FAST)),)),
    ])
    ended = (
        Assign(verdict, Const(0)),
        If(ir.IsNone(cell("attempt_fault")), judge_end),
        Assign(cell("phase"), idle),
        *changed,
        If(ir.And((ir.Compare("==", verdict, Const(0)), ir.IsNone(cell("attempt_fault")))),
           (count("completed"),)),
    )
    judge_running = ir.if_chain([
        (ir.And((ir.Compare("<", y, alpha),
                 ir.Compare(">=", ir.Add(x, ir.Sub(alpha, y)), gamma))),
         (Assign(verdict, Const(CANNOT_FINISH)),)),
        (ir.And((ir.Compare(">=", y, alpha), ir.Compare(">=", x, gamma))),
         (Assign(verdict, Const(DEADLINE)),)),
        (ir.Or((ir.Compare(">", y, beta),
                ir.And((ir.Compare("==", y, beta), is_(phase, running))))),
         (Assign(verdict, Const(OVERRUN)),)),
    ])
    goes_on = (
        Assign(verdict, Const(0)),
        *ir.if_chain([
            (ir.And((is_(phase, running), suspend)),
             (Assign(cell("phase"), suspended), Assign(phase, suspended), *changed)),
            (ir.And((is_(phase, suspended), resume)),
             (Assign(cell("phase"), running), Assign(phase, running), *changed)),
        ]),
        If(ir.IsNone(cell("attempt_fault")), judge_running),
    )
    works = (
        Assign(el, ir.Sub(Now(), cell("last_us"))),
        Assign(cell("last_us"), Now()),
        Assign(x, ir.Add(cell("x_us"), el)),
        Assign(cell("x_us"), x),
        If(is_(phase, running), (Assign(y, ir.Add(cell("y_us"), el)), Assign(cell("y_us"), y)),
           (Assign(y, cell("y_us")),)),
        Assign(e, end),
        If(e, ended, goes_on),
        If(ir.And((armed, ir.Compare(">=", x, gamma))),
           (Do(Call(watchdog, "trip", (Now(), ir.ScanNumber(), x,
                                                  cell("attempt")))),
            *changed)),
        If(e, (Assign(armed, FALSE),)),
        If(ir.And((ir.Compare("!=", verdict, Const(0)), ir.IsNone(cell("attempt_fault")))),
           (Do(Call(a, "detect", (verdict, Now(), ir.ScanNumber()))), *mark)),
    )
    return (
        Assign(phase, cell("phase")),
        If(is_(phase, idle), (If(start, begin),), works),
    )
