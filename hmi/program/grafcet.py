"""GRAFCET (IEC 60848) at a scan, written once: the step times (stage 2), the enabling and
firing of the transitions and the continuous actions (stage 5), lowered into the scan
program. docs/grafcet.md states the interpretation, hmi.engine.grafcet keeps the state.

* A step's activity time is the time since it was activated, in its time slot; an inactive
  step's time slot holds 0 (the runtime writes 0 when it deactivates a step, and when it
  resets the GRAFCET), so only the active steps' slots are written at stage 2.
* A transition is fireable when all its upstream steps are active and its receptivity is
  true, both read on the image at that point of the scan; all fireable transitions fire
  together, once per scan (rule 4): the program collects them and hands them to the
  runtime's ``fire(fire, image, now)`` (its new steps, their stored actions, the firing
  numbers the snapshot shows); when none is fireable, ``fired`` is emptied.
* A continuous action holds its output while its step is active (and its condition true):
  every output such an action drives is first set to 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hmi.logic.expr import Node
from hmi.program import ir
from hmi.program.ir import (
    FALSE,
    TRUE,
    Assign,
    Call,
    Cell,
    Const,
    Do,
    If,
    Local,
    Now,
    Slot,
    Stmt,
    Test,
)


def lower_step_times(since: list[int | None], steps: Sequence[tuple[int, int]]
                     ) -> tuple[Stmt, ...]:
    """Stage 2: each active step's time, from its activation time (`since`, the runtime's
    list, one entry per step; `steps`: (step slot, time slot) in the same order)."""
    table = ir.Ref(since)
    return tuple(If(Slot(step), (Assign(Slot(time), ir.Sub(Now(), ir.Item(table, k))),))
                 for k, (step, time) in enumerate(steps))


def lower_evolution(runtime: Any, transitions: Sequence[tuple[Sequence[int], Node]]
                    ) -> tuple[Stmt, ...]:
    """Stage 5's evolution: the fireable transitions (upstream step slots, receptivity),
    in declaration order, fired together by the runtime."""
    fire = Local("fire")
    body: list[Stmt] = [Assign(fire, Const(()))]  # (a tuple grown only when one is fireable)
    for k, (sources, receptivity) in enumerate(transitions):
        test = ir.all_of(*(Slot(s) for s in sources), Test(receptivity))
        body.append(If(test, (Assign(fire, ir.Add(fire, Const((k,)))),)))
    body.append(If(fire, (Do(Call(runtime, "fire", (fire, ir.TheImage(), Now()))),),
                   (Assign(Cell(runtime, "fired"), Const(())),)))
    return tuple(body)


def lower_continuous(driven: Sequence[int],
                     actions: Sequence[tuple[int, int, Node | None]]) -> tuple[Stmt, ...]:
    """The continuous actions (step slot, output slot, condition or None), after the
    evolution: every driven output 0, then 1 where an active step's action holds."""
    body: list[Stmt] = [Assign(Slot(slot), FALSE) for slot in driven]
    for step, target, condition in actions:
        test = Slot(step) if condition is None else ir.all_of(Slot(step), Test(condition))
        body.append(If(test, (Assign(Slot(target), TRUE),)))
    return tuple(body)
