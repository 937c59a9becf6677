"""Recovery procedures at a scan, written once: which procedures the cell needs (every scan,
in every mode) and the running procedure's steps (stage 5 in recovery mode), lowered into
the scan program. hmi.engine.recovery keeps the state and says it in words.

* A procedure is needed once its `needed` condition has held for its `for` time: the
  program keeps since when it holds (``needed_since``, per procedure) and, when some
  condition holds, hands the judgement to the stage (``judge_needed(now)``: which ones held
  long enough); when none holds, nothing is needed.
* A running procedure goes through its steps in order: a step ends when its `until` holds
  (for its `for` time, if it has one: ``held_since``), several in one scan if they all hold;
  past the last one the procedure is done (``finish(now)``), past its timeout it failed
  (``fail(now)``): the outputs are then the safe vector. Else the step's actions give the
  outputs it drives (its condition, or 1), every other output its safe value.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hmi.program import ir
from hmi.program.ir import FALSE, TRUE, Assign, Call, Cell, Const, Do, If, Local, Now, Stmt, Test
from hmi.project.model import RecoveryProcedure


def lower_needed(stage: Any, procedures: Sequence[tuple[Any, RecoveryProcedure]]
                 ) -> tuple[Stmt, ...]:
    """Which of the procedures (each with the runtime object holding its ``needed_since``)
    the cell needs now."""
    watched = [(proc, spec) for proc, spec in procedures if spec.needed is not None]
    if not watched:
        return (Assign(Cell(stage, "needed"), Const(())),)
    moved = Local("moved")
    body: list[Stmt] = [Assign(moved, FALSE)]
    for proc, spec in watched:
        assert spec.needed is not None
        since = Cell(proc, "needed_since")
        body.append(If(Test(spec.needed.when.root),
                       (Assign(moved, TRUE), If(ir.IsNone(since), (Assign(since, Now()),))),
                       (Assign(since, ir.NONE),)))
    body.append(If(moved, (Do(Call(stage, "judge_needed", (Now(),))),),
                   (Assign(Cell(stage, "needed"), Const(())),)))
    return tuple(body)


def lower_procedure(stage: Any, spec: RecoveryProcedure, outputs: Sequence[str],
                    safe: Sequence[bool]) -> tuple[Stmt, ...]:
    """One scan of `spec` while it is the stage's procedure: the local ``f`` is the vector it
    asks for (`outputs` in the image's order, `safe` their safe values)."""
    vector = Local("f")
    safe_vector = ir.Tuple(tuple(Const(bool(value)) for value in safe))
    step = Local("s")
    held = Cell(stage, "held_since")
    body: list[Stmt] = [Assign(step, Cell(stage, "step"))]
    for k, rstep in enumerate(spec.steps):
        advance = (Assign(Cell(stage, "step"), Const(k + 1)), Assign(held, ir.NONE),
                   Assign(step, Const(k + 1)))
        if rstep.for_us:
            ends: tuple[Stmt, ...] = (
                If(ir.IsNone(held), (Assign(held, Now()),)),
                If(ir.Compare(">=", ir.Sub(Now(), held), Const(int(rstep.for_us))), advance))
        else:
            ends = advance
        body.append(If(ir.Compare("==", step, Const(k)),
                       (If(Test(rstep.until.root), ends, (Assign(held, ir.NONE),)),)))
    index = {name: k for k, name in enumerate(outputs)}
    cases = []
    for k, rstep in enumerate(spec.steps):
        values: list[ir.Value] = [Const(bool(value)) for value in safe]
        for action in rstep.actions:
            values[index[action.output]] = (TRUE if action.condition is None
                                            else Test(action.condition.root))
        cases.append((k, (Assign(vector, ir.Tuple(tuple(values))),)))
    body.append(Assign(vector, safe_vector))
    body.append(If(ir.Compare(">=", step, Const(len(spec.steps))),
                   (Do(Call(stage, "finish", (Now(),))),),
                   ir.if_chain([(ir.Compare(">=", ir.Sub(Now(), Cell(stage, "started_us")),
                                            Const(int(spec.timeout_us))),
                                 (Do(Call(stage, "fail", (Now(),))),))],
                               (ir.Switch(step, tuple(cases)),))))
    return (If(Cell(stage, "running"), tuple(body), (Assign(vector, safe_vector),)),)
