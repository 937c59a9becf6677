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

from collections.abc import Mapping
from typing import Any, ClassVar

from hmi.plant.sim.device import FaultSpec, ParamSpec, SimDevice

NL_PER_L = 1_000_000_000


def litres(value: float) -> int:
    """A volume in litres as integer nanolitres."""
    return round(float(value) * NL_PER_L)


def ml_per_s(value: float) -> int:
    """A flow in litres per second as integer millilitres per second (= nL per µs)."""
    return round(float(value) * 1000)


class Tank(SimDevice):
    MODEL = "tank"
    DESCRIPTION = "tank with low and high level switches and a gravity drain"
    SENSORS = ("low", "high")
    ACTUATORS = ()
    PARAMS: ClassVar[dict[str, ParamSpec]] = {
        "capacity": ParamSpec("number", 100.0, "volume in litres at which it spills over",
                              minimum=1),
        "initial": ParamSpec("number", 0.0, "volume at start, in litres", minimum=0),
        "low": ParamSpec("number", 20.0, "height of the low switch, in litres", minimum=0),
        "high": ParamSpec("number", 80.0, "height of the high switch, in litres", minimum=0),
        "drain": ParamSpec("number", 0.0, "gravity drain through the hand valve, in L/s",
                           minimum=0, maximum=1000),
        "drain_to": ParamSpec("device", None, "the tank the drain runs into (default: out of "
                              "the cell)", ("tank",)),
    }
    FAULTS: ClassVar[dict[str, FaultSpec]] = {
        "low_stuck0": FaultSpec("low_stuck0", "low level switch stuck at 0", "low"),
        "low_stuck1": FaultSpec("low_stuck1", "low level switch stuck at 1", "low"),
        "high_stuck0": FaultSpec("high_stuck0", "high level switch stuck at 0", "high"),
        "high_stuck1": FaultSpec("high_stuck1", "high level switch stuck at 1", "high"),
    }

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

    @classmethod
    def param_problems(cls, params: Mapping[str, Any]) -> list[tuple[str, str, str]]:
        values = {k: spec.default for k, spec in cls.PARAMS.items()} | dict(params)
        problems = []
        if not values["low"] < values["high"]:
            problems.append(("high", f"the high switch ({values['high']:g} L) is not above the "
                             f"low one ({values['low']:g} L)", "low < high"))
        if values["high"] > values["capacity"]:
            problems.append(("high", f"the high switch ({values['high']:g} L) is above the "
                             f"capacity ({values['capacity']:g} L)", "high <= capacity"))
        if values["initial"] > values["capacity"]:
            problems.append(("initial", f"the initial volume ({values['initial']:g} L) is above "
                             f"the capacity ({values['capacity']:g} L)", "initial <= capacity"))
        return problems

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
