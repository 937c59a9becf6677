"""The functional control law at run time: GRAFCET evolution, then equations.

Order within the control phase: the GRAFCET evolves (and its stored actions apply), its
continuous actions set their outputs, then the equations run in the order written. An
equation reads the current image: a variable already computed this scan has its new value,
any other its value from the previous scan — the PLC's own semantics.
"""

from __future__ import annotations

from collections.abc import Mapping

from hmi.engine.grafcet import GrafcetRuntime
from hmi.logic.expr import BoolFn, compile_bool
from hmi.project.model import ControlLaw


class ControlRuntime:
    def __init__(self, law: ControlLaw, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int]):
        self.law = law
        self.grafcet = (GrafcetRuntime(law.grafcet, slots, step_time_slots)
                        if law.grafcet else None)
        self.equations: list[tuple[int, BoolFn | None, BoolFn | None, BoolFn | None, bool]] = []
        for eq in law.equations:
            slot = slots[eq.target]
            if eq.expr is not None:
                self.equations.append((slot, compile_bool(eq.expr, slots, step_time_slots),
                                       None, None, False))
            else:
                self.equations.append((slot, None, compile_bool(eq.set, slots, step_time_slots),
                                       compile_bool(eq.reset, slots, step_time_slots),
                                       eq.set_dominant))

    def reset(self, image: list, now: int) -> None:
        if self.grafcet:
            self.grafcet.reset(image, now)

    def update_times(self, image: list, now: int) -> None:
        if self.grafcet:
            self.grafcet.update_times(image, now)

    def run(self, image: list, history, now: int) -> None:
        if self.grafcet:
            self.grafcet.evolve(image, history, now)
            self.grafcet.apply_continuous(image, history)
        for slot, expr, set_, reset, set_dominant in self.equations:
            if expr is not None:
                image[slot] = expr(image, history)
            elif set_dominant:
                image[slot] = set_(image, history) or (image[slot] and not reset(image, history))
            else:
                image[slot] = not reset(image, history) and (set_(image, history) or image[slot])

    def active_steps(self, image: list) -> tuple[str, ...]:
        return self.grafcet.active(image) if self.grafcet else ()

    @property
    def fired(self) -> tuple[int, ...]:
        return self.grafcet.fired if self.grafcet else ()
