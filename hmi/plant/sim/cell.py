"""What the box-handling cell models (sorting, palletizer) share: physics integrated in fixed
steps, and the usual faults — each drive's jam, each sensor stuck at 0 or 1 (see
:func:`hmi.project.device_models.jam_and_stuck_faults`).

A subclass gives its sensors as the physics has them (:meth:`true_sensors`), one physics step
(:meth:`_step`) and what the jams do (:meth:`_jams_changed`); a stuck sensor is applied here,
over the true value, so no model can forget it. A repair (the technician's, in training)
clears both: the drives move again and the sensors read the truth, from where the cell is.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

from hmi.plant.sim.device import PendingFault, SimDevice


class SteppedCell(SimDevice):
    REPAIRABLE = True
    MAX_STEP_US: ClassVar[int] = 5_000  # physics step: at 300 mm/s a box moves 1.5 mm

    def __init__(self, name: str, params: Mapping[str, Any]):
        super().__init__(name, params)
        self.jams: set[str] = set()
        self.stuck: dict[str, bool] = {}  # sensor -> the value it is stuck at

    @abstractmethod
    def true_sensors(self) -> dict[str, bool]:
        """The sensors as the physics has them, before any stuck fault."""

    def sensors(self) -> dict[str, bool]:
        values = self.true_sensors()
        values.update(self.stuck)
        return values

    def _advance_to(self, t: int) -> None:
        while self.t < t:
            dt = min(t - self.t, self.MAX_STEP_US)
            self.t += dt
            self._step(dt)

    @abstractmethod
    def _step(self, dt: int) -> None:
        """Integrate the physics over dt microseconds (self.t is already the end)."""

    def _fault_activated(self, fault: PendingFault) -> None:
        code = fault.code
        if code.endswith(("_stuck0", "_stuck1")):
            self.stuck[code.rsplit("_", 1)[0]] = code.endswith("1")
        else:
            self.jams.add(code)
            self._jams_changed()

    def _repaired(self) -> None:
        self.jams.clear()
        self.stuck.clear()
        self._jams_changed()

    @abstractmethod
    def _jams_changed(self) -> None:
        """Hook: the drives named in `self.jams` stop moving, the others move again."""
