"""A centrifugal pump drawing from a tank and pushing through two valved lines (000 §3.3).

Physics: while it runs, the pump delivers `flow` L/s shared between its two discharge lines
in proportion to how far each line's valve is open (the valve devices named by `valve_a`,
`valve_b`; a valve is shut while its closed end switch would be made and fully open once its
open one would be, linear in between); with the lines together less than fully open it
delivers that fraction of `flow`. Line a leads into the tank `to_a`, line b into `to_b` (either may
be the suction tank: a recirculation). Water comes from the tank `suction`; below
`dry_level` litres in it the pump draws air and delivers nothing. Flows are integrated per
step of the plant (one scan) from the valves' positions at the end of the step, in integer
nanolitres (hmi/plant/sim/tank.py). The openings are exact fractions (:func:`opening`); a step
computes with their numerators over one common denominator, in integers, for the very same
results at a fraction of the cost (the plant runs at every scan).

The order ``P`` starts and stops it; the sensor ``run`` is its running feedback (an auxiliary
contact of the motor contactor).

Damage events:
  ``dead_head``  running with its lines together less than `min_opening` open (both valves
                 shut, or barely cracked) for longer than `deadhead_tolerance`: the water
                 churns in the casing and overheats (once per episode);
  ``dry_run``    running with the suction tank below `dry_level` for longer than
                 `dry_tolerance`: the seal runs dry (once per episode).

Faults, each injected at a time:
  ``no_start``  the motor does not start at the next start order (a burnt coil, a tripped
                breaker): ``run`` stays 0, nothing flows;
  ``welded``    the contactor welds: the pump does not stop when the order drops (from the
                next stop order on, for good).
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping
from fractions import Fraction
from typing import Any

from hmi.plant.sim.device import SimDevice
from hmi.plant.sim.tank import NL_PER_L, Tank, litres, ml_per_s
from hmi.plant.sim.valve import Valve
from hmi.project.device_models import PUMP
from hmi.timefmt import seconds


class Pump(SimDevice, model=PUMP):
    REPAIRABLE = True

    def __init__(self, name: str, params: Mapping[str, Any]):
        super().__init__(name, params)
        self.flow = ml_per_s(self.params["flow"])
        self.dry_at = litres(self.params["dry_level"])
        self.suction: Tank | None = None
        self.lines: list[tuple[Valve, Tank | None]] = []
        self.running = False
        self.delivering = 0  # mL/s during the last step, for the display
        self.dead_us = 0
        self.dry_us = 0
        self.dead_reported = False
        self.dry_reported = False
        self.starts = 0
        # The lines' openings over one denominator (see link); min_opening as p / q.
        self._scales: tuple[int, ...] = ()
        self._denominator = 1
        limit = Fraction(self.params["min_opening"])
        self._min_opening = (limit.numerator, limit.denominator)

    def link(self, devices: Mapping[str, SimDevice]) -> None:
        def get(key: str) -> Any:
            name = self.params.get(key)
            return devices[name] if name else None
        self.suction = get("suction")
        self.lines = [(get(v), get(t)) for v, t in (("valve_a", "to_a"), ("valve_b", "to_b"))
                      if get(v) is not None]
        # opening(valve) = n / span; over the common denominator D (the product of the
        # spans) it is n * (D // span) / D: integers only from here on.
        spans = [valve.travel - 2 * valve.band for valve, _ in self.lines]
        self._denominator = math.prod(spans)
        self._scales = tuple(self._denominator // span for span in spans)

    def _repaired(self) -> None:
        """A repaired motor and contactor follow the order again from now: a welded contactor
        released stops a pump whose order is off; a repaired motor whose order is on runs."""
        order = self.orders["P"]
        if order and not self.running:
            self.running = True
            self.starts += 1
        elif not order and self.running:
            self.running = False
            self.dead_us = self.dry_us = 0
            self.dead_reported = self.dry_reported = False

    # -- orders -------------------------------------------------------------------------------
    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        if "P" not in changed:
            return
        if changed["P"] and not self.running:
            if "no_start" in self.active_faults:
                self.record(t, "start_failed", False, "start ordered, the motor did not start")
                return
            self.running = True
            self.starts += 1
        elif not changed["P"] and self.running:
            if "welded" in self.active_faults:
                self.record(t, "stop_failed", False, "stop ordered, the contactor stayed closed")
                return
            self.running = False
            self.dead_us = self.dry_us = 0
            self.dead_reported = self.dry_reported = False

    # -- physics ------------------------------------------------------------------------------
    def _advance_to(self, t: int) -> None:
        dt = t - self.t
        self.t = t
        if dt <= 0:
            return
        if not self.running:
            self.delivering = 0
            return
        for valve, tank in self.lines:
            valve.advance(t)
            if tank is not None:
                tank.advance(t)
        suction = self.suction
        if suction is not None:
            suction.advance(t)
        self._check_dead_head(t, dt)
        if suction is not None and suction.volume < self.dry_at:
            self.delivering = 0
            self.dry_us += dt
            if self.dry_us > self.params["dry_tolerance"] and not self.dry_reported:
                self.dry_reported = True
                self.record(t, "dry_run", True, f"pump {self.name} ran dry (tank {suction.name} "
                            f"below {self.dry_at / NL_PER_L:g} L) for more than "
                            f"{seconds(self.params['dry_tolerance'])} s")
            return
        self.dry_us = 0
        self.dry_reported = False
        self._deliver(t, dt)

    def _openings(self) -> list[int]:
        """Each line's :func:`opening` times the common denominator (an integer)."""
        return [_open_span(valve) * scale
                for (valve, _), scale in zip(self.lines, self._scales, strict=True)]

    def _check_dead_head(self, t: int, dt: int) -> None:
        # sum(opening) < min_opening, as sum(numerators) / D < p / q
        p, q = self._min_opening
        if self.lines and sum(self._openings()) * q < p * self._denominator:
            self.dead_us += dt
            if self.dead_us > self.params["deadhead_tolerance"] and not self.dead_reported:
                self.dead_reported = True
                closed = ", ".join(valve.name for valve, _ in self.lines)
                self.record(t, "dead_head", True, f"pump {self.name} ran against shut "
                            f"valves ({closed}) for more than "
                            f"{seconds(self.params['deadhead_tolerance'])} s: it overheats")
        else:
            self.dead_us = 0
            self.dead_reported = False

    def _deliver(self, t: int, dt: int) -> None:
        """Move this step's water from the suction tank into the lines' tanks."""
        openings = self._openings()
        total = sum(openings)  # the lines' opening together, over the denominator
        if total == 0:
            self.delivering = 0
            return
        # With fractions f_i = openings_i / D, total T = total / D and share = min(1, T):
        # delivering = flow * share and line i gets flow * dt * share * f_i / T, truncated.
        # Every term is a non-negative integer ratio, so truncating is floor division: at
        # T >= 1 line i gets flow * dt * openings_i // total, below it flow * dt *
        # openings_i // D (share / T = 1 / D).
        flow, denominator = self.flow, self._denominator
        if total >= denominator:
            self.delivering = flow
            volumes = [flow * dt * f // total for f in openings]
        else:
            self.delivering = flow * total // denominator
            volumes = [flow * dt * f // denominator for f in openings]
        available = self.suction.take(sum(volumes)) if self.suction is not None else sum(volumes)
        if available < sum(volumes):  # the tank emptied during the step: share what came
            volumes = [v * available // sum(volumes) for v in volumes]
        for (_, tank), volume in zip(self.lines, volumes, strict=True):
            if tank is not None:
                tank.add(t, volume)

    def sensors(self) -> dict[str, bool]:
        return {"run": self.running}

    # -- reporting ----------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        # 0/1, not a bool: in a plant's state a true bool is an abnormal condition (a jam),
        # which the HMI shows as an alarm; a running pump is not one.
        return {"running": int(self.running), "flow": round(self.delivering / 1000, 1)}

    def counters(self) -> dict[str, int]:
        return {"starts": self.starts}

    def state_key(self) -> Hashable:
        return (self.running, self.delivering)

    def counters_key(self) -> Hashable:
        return self.starts


def opening(valve: Valve) -> Fraction:
    """How far a valve lets water through: 0 while its closed switch would be made (the valve
    rests there, `band` from its end, after a closing), 1 once its open switch would be."""
    return Fraction(_open_span(valve), valve.travel - 2 * valve.band)


def _open_span(valve: Valve) -> int:
    """The numerator of :func:`opening` (its denominator is the valve's span)."""
    return max(0, min(valve.pos - valve.band, valve.travel - 2 * valve.band))
