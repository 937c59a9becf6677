"""The functional control law at run time: GRAFCET evolution, then equations.

Order within the control phase: the GRAFCET evolves (and its stored actions apply), its
continuous actions set their outputs, then the equations run in the order written. An
equation reads the current image: a variable already computed this scan has its new value,
any other its value from the previous scan — the PLC's own semantics.
"""

from __future__ import annotations

from collections.abc import Mapping

from hmi.engine.grafcet import GrafcetRuntime
from hmi.logic.expr import BoolFn, History, Image, compile_bool
from hmi.project.model import ControlLaw

ASSIGN, SET_DOMINANT, RESET_DOMINANT = 0, 1, 2  # the kinds of equation


class ControlRuntime:
    def __init__(self, law: ControlLaw, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int]):
        self.law = law
        self.grafcet = (GrafcetRuntime(law.grafcet, slots, step_time_slots)
                        if law.grafcet else None)
        # (target slot, kind, expression or set, reset or unused), in the order written
        self.equations: list[tuple[int, int, BoolFn, BoolFn]] = []
        for eq in law.equations:
            slot = slots[eq.target]
            if eq.expr is not None:
                fn = compile_bool(eq.expr, slots, step_time_slots)
                self.equations.append((slot, ASSIGN, fn, fn))
            else:
                assert eq.set is not None and eq.reset is not None  # the loader's guarantee
                self.equations.append((slot, SET_DOMINANT if eq.set_dominant else RESET_DOMINANT,
                                       compile_bool(eq.set, slots, step_time_slots),
                                       compile_bool(eq.reset, slots, step_time_slots)))

    def reset(self, image: Image, now: int) -> None:
        if self.grafcet:
            self.grafcet.reset(image, now)

    def update_times(self, image: Image, now: int) -> None:
        if self.grafcet:
            self.grafcet.update_times(image, now)

    def run(self, image: Image, history: History, now: int) -> None:
        if self.grafcet:
            self.grafcet.evolve(image, history, now)
            self.grafcet.apply_continuous(image, history)
        for slot, kind, set_, reset in self.equations:
            if kind == ASSIGN:
                image[slot] = set_(image, history)
            elif kind == SET_DOMINANT:
                image[slot] = set_(image, history) or (image[slot] and not reset(image, history))
            else:
                image[slot] = not reset(image, history) and (set_(image, history) or image[slot])

    def capture(self) -> tuple[dict[str, int], tuple[int, ...]] | None:
        """The GRAFCET's activation times and last firing (its steps live in the image)."""
        if self.grafcet is None:
            return None
        return dict(self.grafcet.activated_at), self.grafcet.fired

    def restore(self, state: tuple[dict[str, int], tuple[int, ...]] | None) -> None:
        if self.grafcet is not None and state is not None:
            self.grafcet.activated_at = dict(state[0])
            self.grafcet.fired = state[1]
            self.grafcet.forget_active()

    def active_steps(self, image: Image) -> tuple[str, ...]:
        return self.grafcet.active(image) if self.grafcet else ()

    @property
    def fired(self) -> tuple[int, ...]:
        return self.grafcet.fired if self.grafcet else ()
