"""An assembly robot that transfers pallets: the robot of 002 §4 (Fig. 8).

Physics: at home the robot is free (``e`` = 1). When the transfer order ``G`` rises it takes
the pallet and works for ``work`` (the transfer to the assembly station, its task); then it
reports the end (``R`` = 1) and holds until ``G`` drops, when it returns home in
``return_time`` and is free again. Dropping ``G`` before the end aborts the task (the robot
returns home; recorded, not damage). An order while the robot is busy is ignored (recorded).

Faults, each injected at a time, optionally for a duration, else for good:
  stop  the robot pauses (a protective stop that clears by itself): no progress, the logical
        sensor ``halted`` reads 1 - the interruption of the robot task;
  skip  the part is missing: the robot ends its current task at once (or its next one, if
        idle) and reports R, far faster than normal.
A repair (training) clears the stop at once and disarms a skip not yet used.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

from hmi.plant.sim.device import PendingFault, SimDevice
from hmi.plant.sim.tasks import TaskLog, TaskRecord
from hmi.project.device_models import ROBOT

_NEVER = 1 << 62
HOME, WORKING, DONE, RETURNING = "home", "working", "done", "returning"


class Robot(SimDevice, model=ROBOT):
    REPAIRABLE = True

    def __init__(self, name: str, params: dict[str, Any]):
        super().__init__(name, params)
        self.work = int(self.params["work"])
        self.return_time = int(self.params["return_time"])
        self.mode = HOME
        self.progress = 0
        self.halt_until = 0
        self.skip_armed = False
        self.log = TaskLog()
        self.transfers = 0

    @property
    def halted(self) -> bool:
        return self.t < self.halt_until

    def sensors(self) -> dict[str, bool]:
        return {"e": self.mode == HOME, "R": self.mode == DONE, "halted": self.halted}

    # -- physics ---------------------------------------------------------------------------
    def _advance_to(self, t: int) -> None:
        while self.t < t:
            step = t - self.t
            if self.halt_until > self.t:
                step = min(step, self.halt_until - self.t)
            goal = {WORKING: self.work, RETURNING: self.return_time}.get(self.mode)
            if goal is not None and not self.halted:
                step = min(step, goal - self.progress)
                self.progress += step
                if self.mode == WORKING:
                    self.log.worked(step)
            self.t += step
            if goal is not None and self.progress >= goal:
                self._reached_goal()

    def _reached_goal(self) -> None:
        if self.mode == WORKING:
            self._end_task()
        elif self.mode == RETURNING:
            self.mode = HOME

    def _end_task(self) -> None:
        self.mode = DONE
        self.transfers += 1
        self.log.finish(self.t)

    def _fault_activated(self, fault: PendingFault) -> None:
        if fault.code == "stop":
            until = _NEVER if fault.duration_us is None else fault.at_us + fault.duration_us
            self.halt_until = max(self.halt_until, until)
        elif fault.code == "skip":
            if self.mode == WORKING:
                self._end_task()
            else:
                self.skip_armed = True

    def _repaired(self) -> None:
        """The protective stop clears now; a part reported missing is there again."""
        self.halt_until = min(self.halt_until, self.t)
        self.skip_armed = False

    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        if "G" not in changed:
            return
        if changed["G"]:
            if self.mode != HOME:
                self.record(t, "order_ignored", False, f"transfer order G while the robot is "
                            f"{self.mode}")
                return
            self.mode, self.progress = WORKING, 0
            self.log.begin(t)
            if self.skip_armed:
                self.skip_armed = False
                self._end_task()
            return
        if self.mode == WORKING:
            self.record(t, "order_dropped_midway", False, "transfer order G dropped before "
                        "the end of the task; the robot returns home")
            self.log.finish(t, aborted=True)
        if self.mode in (WORKING, DONE):
            self.mode, self.progress = RETURNING, 0
            if self.return_time == 0:
                self.mode = HOME

    # -- reporting -------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"mode": self.mode, "halted": self.halted}

    def counters(self) -> dict[str, int]:
        return {"transfers": self.transfers}

    def state_key(self) -> Hashable:
        return (self.mode, self.halted)

    def counters_key(self) -> Hashable:
        return self.transfers

    def task_records(self) -> tuple[TaskRecord, ...]:
        """Each transfer: order given, end reported, time actually worked."""
        return self.log.records()
