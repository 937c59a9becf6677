"""The functional control law at run time: GRAFCET evolution, then equations.

Order within the control phase: the GRAFCET evolves (and its stored actions apply), its
continuous actions set their outputs, then the equations run in the order written. An
equation reads the current image: a variable already computed this scan has its new value,
any other its value from the previous scan — the PLC's own semantics.

In manual mode the program waits (GEMMA's F4, S7-GRAPH's MAN mode): the engine does not run
the law, so no transition fires and no equation is evaluated (its steps and memories hold in
the image), and the step times stop where they were (:meth:`ControlRuntime.hold`). Leaving
manual mode (:meth:`ControlRuntime.resume`) shifts the activation times by the time spent
waiting: the program resumes from the steps where it waited, their times going on from where
they stopped.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

from hmi.engine.codegen import Vocabulary
from hmi.engine.grafcet import GrafcetRuntime
from hmi.logic.expr import Image
from hmi.program import order
from hmi.program.ir import Stmt
from hmi.program.memories import lower_equation
from hmi.project.model import ControlLaw


class ControlState(NamedTuple):
    """What ControlRuntime.capture copies (the steps and memories live in the image)."""

    activated_at: dict[str, int] | None  # None: no GRAFCET
    fired: tuple[int, ...]
    held_since: int | None  # manual mode: the program waits since then


class ControlRuntime:
    # the GRAFCET's firing (hmi.program.grafcet; the equations are slots alone)
    PRINTED = Vocabulary(frozenset({"fire", "fired"}), frozenset({"fire"}))

    def __init__(self, law: ControlLaw, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int]):
        self.law = law
        self.grafcet = (GrafcetRuntime(law.grafcet, slots, step_time_slots)
                        if law.grafcet else None)
        # Stage 5 as the scan program (hmi.program): the GRAFCET's evolution and continuous
        # actions, then the equations in the order written; and the step times of stage 2
        self.equations = tuple(stmt for eq in law.equations
                               for stmt in lower_equation(eq, slots[eq.target]))
        self.program: tuple[Stmt, ...] = (
            self.grafcet.evolution if self.grafcet is not None else ()) + self.equations
        self.times: tuple[Stmt, ...] = self.grafcet.times if self.grafcet is not None else ()
        # The scan time the program has waited since (manual mode), None while it runs.
        self.held_since: int | None = None

    @property
    def parts(self) -> dict[str, tuple[Stmt, ...]]:
        return {order.STEP_TIMES: self.times, order.LAW: self.program}

    def reset(self, image: Image, now: int) -> None:
        if self.grafcet:
            self.grafcet.reset(image, now)
        if self.held_since is not None:  # (the first scan, in manual mode: it waits from here)
            self.held_since = now

    def hold(self, now: int) -> None:
        """Manual mode: the program waits from `now` (the last scan's time). The engine no
        longer runs it; the step times in the image stay as that scan left them."""
        if self.held_since is None:
            self.held_since = now
            if self.grafcet:
                self.grafcet.fired = ()

    def resume(self, now: int) -> None:
        """Leaving manual mode at `now` (the last scan's time): the activation times move on
        by the time the program waited, so the next scan's step times go on from where they
        stopped."""
        since, self.held_since = self.held_since, None
        if since is not None and self.grafcet is not None and now > since:
            self.grafcet.shift(now - since)

    @property
    def held(self) -> bool:
        return self.held_since is not None

    def capture(self) -> ControlState:
        """The GRAFCET's activation times and last firing (its steps live in the image), and
        since when the program waits (manual mode)."""
        if self.grafcet is None:
            return ControlState(None, (), self.held_since)
        return ControlState(dict(self.grafcet.activated_at), self.grafcet.fired,
                            self.held_since)

    def restore(self, state: ControlState) -> None:
        self.held_since = state.held_since
        if self.grafcet is not None and state.activated_at is not None:
            self.grafcet.activated_at = dict(state.activated_at)
            self.grafcet.fired = state.fired
            self.grafcet.forget_active()

    def active_steps(self, image: Image) -> tuple[str, ...]:
        return self.grafcet.active(image) if self.grafcet else ()

    @property
    def fired(self) -> tuple[int, ...]:
        return self.grafcet.fired if self.grafcet else ()
