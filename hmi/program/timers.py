"""IEC 61131-3 TON and TOF, written once: the lowering of one timer into the scan program.

The state is the runtime's (hmi.logic.timers.TimerRuntime: ``q``, and ``since``, when IN rose
for a TON or fell for a TOF); the output goes to the timer's slot of the image. Both the
compiled scan and the reference interpreter run what is printed from here.
"""

from __future__ import annotations

from hmi.logic.expr import Node
from hmi.logic.timers import TimerRuntime
from hmi.program.ir import (
    FALSE,
    NONE,
    TRUE,
    Assign,
    Cell,
    Const,
    If,
    IsNone,
    Local,
    Now,
    Slot,
    Stmt,
    Sub,
    Test,
    at_least,
)


def lower_timer(runtime: TimerRuntime, slot: int, input_: Node) -> tuple[Stmt, ...]:
    """One scan of `runtime`, its IN the expression `input_`, its Q written to `slot`."""
    since, q = Cell(runtime, "since"), Cell(runtime, "q")
    s = Local("s")
    # IN held since `since` (the first scan it was seen, when `since` is None: now)
    started = (Assign(s, since), If(IsNone(s), (Assign(s, Now()), Assign(since, Now()))))
    reached = at_least(Sub(Now(), s), Const(int(runtime.preset)))
    if runtime.kind == "TON":
        return (
            If(Test(input_),
               (*started, Assign(Local("q"), reached), Assign(q, Local("q"))),
               (Assign(since, NONE), Assign(Local("q"), FALSE), Assign(q, FALSE))),
            Assign(Slot(slot), Local("q")),
        )
    # TOF: Q on with IN; after IN falls, off once it has stayed off for the preset
    return (
        If(Test(input_),
           (Assign(since, NONE), Assign(q, TRUE)),
           (If(q, (*started, If(reached, (Assign(q, FALSE), Assign(since, NONE))))),)),
        Assign(Slot(slot), q),
    )
