"""What the box-handling cell models (sorting, palletizer) share: physics integrated in fixed
steps, and the usual faults — each drive's jam, each sensor stuck at 0 or 1 (see
:func:`hmi.project.device_models.jam_and_stuck_faults`).

A subclass gives its sensors as the physics has them (:meth:`true_sensors`), one physics step
(:meth:`_step`) and what the jams do (:meth:`_jams_changed`); a stuck sensor is applied here,
over the true value, so no model can forget it. A repair (the technician's, in training)
clears both: the drives move again and the sensors read the truth, from where the cell is.

A subclass may also say, after a step, for how many steps the next ones will only move things
on in a straight line (:meth:`_plan_glide`: boxes gliding on a belt, clocks running): those
steps then run as the glide's cheap :meth:`Glide.move`, with the sensors it kept, for exactly
the same result as :meth:`_step` (a step costs little while the cell only glides),
several at once when one advance spans several steps.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar, Protocol

from hmi.plant.sim.device import PendingFault, SimDevice


class Glide(Protocol):
    """Steps a cell vouched for: `steps` more of `dt` whose motion :meth:`carry` makes
    exactly as :meth:`SteppedCell._step` would, while :meth:`holds`; `sensors`, the true
    sensors all along.

    A glide relies on the cell changing only through its own methods: new orders, a fault
    and a repair end it, and so does :meth:`SteppedCell.touch`, which whoever changes a
    cell's physics by hand (a test placing a box, a travel moved) calls. :meth:`holds` only
    checks that the cell still holds the very containers the glide moves (a state restored
    from copies does not)."""

    dt: int
    steps: int
    sensors: dict[str, bool]

    def holds(self, cell: Any) -> bool: ...

    def carry(self, cell: Any, count: int) -> None:
        """The bodies, travels and clocks where `count` steps bring them (each moves by the
        same at every step: `count` at once is `count` one by one)."""


class SteppedCell(SimDevice):
    REPAIRABLE = True
    MAX_STEP_US: ClassVar[int] = 5_000  # physics step: at 300 mm/s a box moves 1.5 mm

    def __init__(self, name: str, params: Mapping[str, Any]):
        super().__init__(name, params)
        self.jams: set[str] = set()
        self.stuck: dict[str, bool] = {}  # sensor -> the value it is stuck at
        self._glide: Glide | None = None  # new orders, a fault, a repair end it
        # The glide the last advance left the cell in (None: it did not move, or no glide):
        # right after that advance it holds without checking again (read_sensors).
        self._vouched: Glide | None = None
        # Steps of the glide that reads already went through but whose motion is not carried
        # yet (settle): a read inside a glide needs only the glide's sensors.
        self._owed = 0

    def settle(self) -> None:
        """The motion the glide owes carried: the bodies where the steps read so far brought
        them. Whatever reads or changes the cell's physics other than a read inside the
        glide (an advance, a write, a fault, a repair, its state, touch) settles first; a
        test that looks at its fields does too."""
        owed = self._owed
        if owed:
            self._owed = 0
            glide = self._glide
            assert glide is not None  # (owed only inside a glide: whatever ends it settles)
            glide.carry(self, owed)

    def advance(self, t: int) -> None:
        self.settle()
        super().advance(t)

    @abstractmethod
    def true_sensors(self) -> dict[str, bool]:
        """The sensors as the physics has them, before any stuck fault."""

    def sensors(self) -> dict[str, bool]:
        self.settle()
        glide = self._glide
        if glide is not None and glide.holds(self):
            values = dict(glide.sensors)
        else:
            values = self.true_sensors()
        values.update(self.stuck)
        return values

    def read_sensors(self) -> dict[str, bool]:
        """:meth:`sensors` right after :meth:`advance` (the plant's read): the glide the
        advance checked or planned holds still, nothing ran in between, so its sensors are
        read without checking it again nor copying them (the caller only reads them)."""
        glide = self._glide
        if glide is None or glide is not self._vouched:
            return self.sensors()
        if self.stuck:
            values = dict(glide.sensors)
            values.update(self.stuck)
            return values
        return glide.sensors

    def sense(self, t: int) -> Mapping[str, bool]:
        """:meth:`SimDevice.sense` taking the common case first: no fault due by t and a glide
        that vouches for every step up to t, moved at once (what :meth:`_advance_to` would
        do, without its loop), and its sensors given (most of a cell's reads, one per scan,
        are that: one call instead of advance and read_sensors)."""
        glide = self._glide
        if glide is not None:
            span = t - self.t
            dt = glide.dt
            count = span // dt
            if count > 0 and count * dt == span and count <= glide.steps and \
                    (count == 1 or dt == self.MAX_STEP_US) and \
                    (not self.pending or self.pending[0].at_us > t) and glide.holds(self):
                glide.steps -= count
                self._owed += count  # (carried when anything needs more than the sensors)
                self.t = t
                self._vouched = glide
                # (a stuck sensor, rare: read_sensors lays it over the glide's)
                return self.read_sensors() if self.stuck else glide.sensors
        self.advance(t)
        return self.read_sensors()

    def _advance_to(self, t: int) -> None:
        self._vouched = None
        if self.t >= t:
            return
        while self.t < t:
            dt = min(t - self.t, self.MAX_STEP_US)
            glide = self._glide
            if glide is not None and glide.steps and glide.dt == dt and glide.holds(self):
                # every whole step of dt up to t that the glide vouches for, at once
                count = min(glide.steps, (t - self.t) // dt)
                glide.steps -= count
                glide.carry(self, count)
                self.t += count * dt
                continue
            self.t += dt
            self._step(dt)
            self._glide = self._plan_glide(dt)
        # a glide checked (holds) then moved, or planned just now: it holds here
        self._vouched = self._glide

    def touch(self) -> None:
        """The cell's physics was changed by hand (anything but its own methods: a box placed
        or moved, a travel moved): the glide it was in ends, the next step is a full one.
        Why a call and not a check at every step: comparing all a glide relies on with what
        the cell holds was about a quarter of the palletizer's simulated time. The motion the
        glide still owes is carried first (settle): whoever sets a position by hand settles
        before, a change that adds to one may come before or after."""
        self.settle()
        self._glide = None
        self._vouched = None

    def _plan_glide(self, dt: int) -> Glide | None:
        """After a step of `dt`: the next steps that only glide (None: none known)."""
        return None

    def repair(self, t: int) -> tuple[str, ...]:
        codes = super().repair(t)
        self._glide = None  # whatever the repair undid, the next step is a full one
        return codes

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
        self._glide = None

    def _repaired(self) -> None:
        self.jams.clear()
        self.stuck.clear()
        self._jams_changed()

    @abstractmethod
    def _jams_changed(self) -> None:
        """Hook: the drives named in `self.jams` stop moving, the others move again."""
