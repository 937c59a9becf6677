"""A belt conveyor with a pallet pusher: the conveyor of 002 §4 (Fig. 8).

Physics: the pusher order ``d`` puts a pallet on the belt at the instant it rises (if the belt
is empty; otherwise the pallets collide, which is damage). The belt carries one pallet at a
time from the pusher to the end stop in ``transport`` at full speed; sensor ``B`` is 1 while a
pallet waits at the end. The ``release`` order (wired to the robot's transfer order in the
conveyor/robot cell) hands that pallet over: ``B`` falls at the instant release rises.

The pallet's progress is an integer count of 1/1000 µs of full-speed travel, so a slipping
belt moves at an exact rational speed and arrival instants are exact integers of µs.

Faults, each injected at a time, optionally for a duration (``stop@1s+2s``), else for good:
  stop  the belt halts: the pallet does not move and the logical sensor ``halted`` reads 1;
        this is the interruption of the conveyor task (002 §2.1: a malfunction that goes
        away without repair);
  slip  the belt slips: pallets move at ``slip_speed`` of full speed (the task runs, slowly:
        its effective work grows beyond beta).
A repair (training) ends a halt or a slip at once.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

from hmi.plant.sim.device import PendingFault, SimDevice
from hmi.plant.sim.tasks import TaskLog, TaskRecord
from hmi.project.device_models import CONVEYOR

SCALE = 1000  # progress units per µs at full speed
_NEVER = 1 << 62


class Conveyor(SimDevice, model=CONVEYOR):
    REPAIRABLE = True

    def __init__(self, name: str, params: dict[str, Any]):
        super().__init__(name, params)
        self.length = int(self.params["transport"]) * SCALE
        self.slip_speed = max(1, round(float(self.params["slip_speed"]) * SCALE))
        self.pallet: int | None = self.length if self.params["initial"] == "loaded" else None
        self.halt_until = 0
        self.slip_until = 0
        self.log = TaskLog()
        self.delivered = 0
        self.handed = 0

    # -- sensors ---------------------------------------------------------------------------
    @property
    def halted(self) -> bool:
        return self.t < self.halt_until

    @property
    def at_end(self) -> bool:
        return self.pallet is not None and self.pallet >= self.length

    def sensors(self) -> dict[str, bool]:
        return {"B": self.at_end, "halted": self.halted}

    # -- physics ---------------------------------------------------------------------------
    def _speed(self) -> int:
        if self.halted:
            return 0
        return self.slip_speed if self.t < self.slip_until else SCALE

    def _advance_to(self, t: int) -> None:
        while self.t < t:
            step = t - self.t
            for boundary in (self.halt_until, self.slip_until):
                if boundary > self.t:
                    step = min(step, boundary - self.t)
            speed = self._speed()
            if self.pallet is not None and not self.at_end and speed:
                remaining = self.length - self.pallet
                step = min(step, -(-remaining // speed))  # ceil: the arrival instant
                self.pallet = min(self.length, self.pallet + speed * step)
                self.log.worked(step)
                if self.at_end:
                    self.t += step
                    self.delivered += 1
                    self.log.finish(self.t)
                    continue
            self.t += step

    def _fault_activated(self, fault: PendingFault) -> None:
        until = _NEVER if fault.duration_us is None else fault.at_us + fault.duration_us
        if fault.code == "stop":
            self.halt_until = max(self.halt_until, until)
        elif fault.code == "slip":
            self.slip_until = max(self.slip_until, until)

    def _repaired(self) -> None:
        """The belt runs again at full speed from now (a halt or a slip ends)."""
        self.halt_until = min(self.halt_until, self.t)
        self.slip_until = min(self.slip_until, self.t)

    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        if changed.get("release") and self.at_end:
            self.pallet = None
            self.handed += 1
        if changed.get("d"):
            if self.pallet is None:
                self.pallet = 0
                self.log.begin(t)
            else:
                where = "waiting at B" if self.at_end else \
                    f"{100 * self.pallet // self.length}% along"
                self.record(t, "pallet_collision", True,
                            f"pusher order d while a pallet is on the belt ({where})")

    # -- reporting -------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "pallet": None if self.pallet is None else round(100 * self.pallet / self.length, 1),
            "halted": self.halted,
            "slipping": self.t < self.slip_until,
        }

    def counters(self) -> dict[str, int]:
        return {"pallets": self.delivered, "handed": self.handed}

    def state_key(self) -> Hashable:
        return (None if self.pallet is None else round(100 * self.pallet / self.length, 1),
                self.halted, self.t < self.slip_until)

    def counters_key(self) -> Hashable:
        return (self.delivered, self.handed)

    def task_records(self) -> tuple[TaskRecord, ...]:
        """Each pallet's transport: placed, arrived at B, time the belt actually moved it."""
        return self.log.records()
