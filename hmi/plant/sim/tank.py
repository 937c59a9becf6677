"""A tank with a low and a high level switch and a gravity drain: the tanks of 000 §3.3.

Physics: the tank holds a volume of water, counted in integer nanolitres so that every flow
over an integer number of microseconds is exact (1 mL/s during 1 µs is 1 nL). It has no
actuator: a pump (hmi/plant/sim/pump.py) fills it through a valve, and a hand valve drains it by
gravity at a constant `drain` rate (while it holds water) into the tank named by `drain_to`,
or out of the cell. Level switches read 1 while the level is at or above their height.
Water that arrives in a full tank spills over: the `overflow` damage event, once per episode
(a new episode once the level is back under the high switch).

Faults, each injected at a time: ``low_stuck0`` / ``low_stuck1`` / ``high_stuck0`` /
``high_stuck1``, a level switch stuck at 0 or 1.

Counters: ``fills``, the times the true level (not the switch) rose to the high switch's
height after being at least 2 % of the capacity below it: the filling cycles the cell
completed, not counting the level wavering around the switch within a scan (the drain and the
pump act on the tank one after the other).
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from typing import Any

from hmi.plant.sim.device import SimDevice
from hmi.project.device_models import TANK

NL_PER_L = 1_000_000_000


def litres(value: float) -> int:
    """A volume in litres as integer nanolitres."""
    return round(float(value) * NL_PER_L)


def ml_per_s(value: float) -> int:
    """A flow in litres per second as integer millilitres per second (= nL per µs)."""
    return round(float(value) * 1000)


class Tank(SimDevice, model=TANK):
    # A stuck level switch is replaced: nothing else to undo (the faults are read live).
    REPAIRABLE = True

    def __init__(self, name: str, params: Mapping[str, Any]):
        super().__init__(name, params)
        self.capacity = litres(self.params["capacity"])
        self.volume = min(self.capacity, litres(self.params["initial"]))
        self.low_at = litres(self.params["low"])
        self.high_at = litres(self.params["high"])
        self.drain = ml_per_s(self.params["drain"])
        self.drain_to: Tank | None = None
        self.rearm_at = self.high_at - self.capacity // 50  # a new fill starts below this
        self.armed = self.volume < self.rearm_at
        self.overflowing = False
        self.fills = 0
        self.spilled = 0  # nL spilled over in all

    def link(self, devices: Mapping[str, SimDevice]) -> None:
        target = self.params.get("drain_to")
        self.drain_to = devices[target] if target else None  # type: ignore[assignment]

    # -- what the pump and other tanks do to it ---------------------------------------------
    def add(self, t: int, nl: int) -> None:
        """Water arrives at time t (the caller advanced this tank to t)."""
        if nl <= 0:
            return
        self.volume += nl
        if self.volume > self.capacity:
            self.spilled += self.volume - self.capacity
            self.volume = self.capacity
            if not self.overflowing:
                self.overflowing = True
                self.record(t, "overflow", True, f"tank {self.name} full "
                            f"({self.capacity / NL_PER_L:g} L): water spills over")
        self._levels()

    def take(self, nl: int) -> int:
        """Remove up to `nl`; return what was there to take."""
        taken = min(nl, self.volume)
        self.volume -= taken
        self._levels()
        return taken

    def _levels(self) -> None:
        if self.volume >= self.high_at:
            if self.armed:
                self.fills += 1
                self.armed = False
        else:
            self.overflowing = False
            if self.volume < self.rearm_at:
                self.armed = True

    # -- physics ------------------------------------------------------------------------------
    def _advance_to(self, t: int) -> None:
        dt = t - self.t
        self.t = t  # first: the tank it drains into may call back (it never advances us)
        if dt <= 0 or not self.drain or not self.volume:
            return
        moved = self.take(self.drain * dt)
        if self.drain_to is not None:
            self.drain_to.advance(t)
            self.drain_to.add(t, moved)

    def sensors(self) -> dict[str, bool]:
        low, high = self.volume >= self.low_at, self.volume >= self.high_at
        active = self.active_faults
        if "low_stuck0" in active:
            low = False
        if "low_stuck1" in active:
            low = True
        if "high_stuck0" in active:
            high = False
        if "high_stuck1" in active:
            high = True
        return {"low": low, "high": high}

    # -- reporting ----------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"level": round(self.volume / NL_PER_L, 1)}

    def counters(self) -> dict[str, int]:
        return {"fills": self.fills}

    def state_key(self) -> Hashable:
        return round(self.volume / NL_PER_L, 1)  # the level shown, not every nanolitre

    def counters_key(self) -> Hashable:
        return self.fills
