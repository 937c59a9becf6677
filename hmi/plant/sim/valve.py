"""A motorised on/off valve with two end switches: the CISPI valve of 000 §3.

Physics: the position runs from 0 (closed) to `travel` (open), in microseconds of travel, so
that one unit of position is one microsecond of motor time. The valve moves only while
exactly one order is on (O opens, C closes) and stops where it is when the order drops. Both
orders together move nothing and are recorded as damage (the motor is driven both ways).
End switches are made within `switch_band` of each end. An order held while the valve cannot
move (at its end stop, or jammed) for longer than `stall_tolerance` is damage.

A real switch is not a clean step (the tolerances a project declares, docs/project-format.md):
it reports each change of the contact `delay` late, and then bounces for `bounce`: the reading
flips back and forth a few times before it settles, the last flip exactly `bounce` after the
first. The flips are drawn from `bounce_seed`, per edge (`bounce_pattern: each`: every edge its
own pattern, seeded by its rank) or once per switch and direction (`same`: every make of fsc
chatters alike, which keeps the valve time-invariant for the exhaustive exploration of the
closed loop). A stuck switch or a glitch (the faults) overrides the reading; the physics
(arrivals, jams, self-driving) follows the contact itself.

Faults (000 §3.1), each injected at a time:
  F1/F2 fsc stuck at 0/1; F3/F4 fso stuck at 0/1;
  F5/F6 valve stuck at its closed / open position (it can still reach it, never leave it);
  F7/F9 unexpected fsc / fso rise: the switch reads 1 for `glitch` while it should be 0
        (at the first moment after injection when it should read 0);
  F8/F10 unexpected fsc / fso fall: the switch reads 0 for `glitch` while it should be 1;
  F11/F12 unexpected movement: from closed (F11) or open (F12) and at rest, the valve drives
        itself to the other end, once;
  F13 blocked between positions: the valve jams where it is if it is between its ends, or
        at `block_at` of its travel the next time it moves.

Between two changes of its dynamics (a mark, a switch edge, the stall limit, a glitch's edge:
:meth:`Valve._next_boundary`) the valve only glides: its position moves on in a straight line,
or its stall clock runs, and its sensors stay as they are. After each advance it plans that
glide (:meth:`Valve._plan_glide`), and an advance or a read that stays inside it moves the
valve there at once (the plant reads the valve at every scan, and its physics'
step, calls and dictionary were over a quarter of the valve project's scan).
"""

from __future__ import annotations

import random
from collections.abc import Hashable, Mapping
from typing import Any

from hmi.plant.sim.device import PendingFault, SimDevice
from hmi.project.device_models import VALVE
from hmi.timefmt import seconds

_NEVER = 1 << 62

# A glide (Valve._plan_glide): up to which time (excluded) it holds, how the position moves
# per microsecond (+1, -1 or 0), whether the stall clock runs instead, and the sensors all along.
Glide = tuple[int, int, bool, dict[str, bool]]


class Valve(SimDevice, model=VALVE):
    REPAIRABLE = True

    def __init__(self, name: str, params: dict[str, Any]):
        super().__init__(name, params)
        self.travel: int = int(self.params["travel"])
        self.band: int = min(int(self.params["switch_band"]), self.travel // 4)
        # Switch zone edges on both sides, where a switch is made and where it breaks, and
        # the ends (_next_boundary: positions where the dynamics change)
        self._marks = (0, self.band, self.band + 1, self.travel - self.band - 1,
                       self.travel - self.band, self.travel)
        self.pos: int = 0 if self.params["initial"] == "closed" else self.travel
        self.jammed = False
        self.self_drive = 0  # +1 / -1 while F11 / F12 moves the valve by itself
        self.glitches: dict[str, tuple[bool, int, int]] = {}  # sensor -> (value, start, end)
        self.armed: set[str] = set()
        self.stall_us = 0
        self.stall_reported = False
        self.both_on = False
        self.was_open = self.pos >= self.travel - self.band
        self.cycles = 0
        self.opens = 0
        self.closes = 0
        # The glide the valve is in (None: the next advance steps in full). Anything that
        # changes its dynamics ends it (_settle: new orders, a fault, a repair, a mark
        # reached); whoever changes its physics by hand calls touch().
        self._glide: Glide | None = None
        # The switches as they read before any fault (delay, bounce): the contact's value, and
        # the changes still to come out of the switch, (time, sensor, value) in time order.
        # Without delay nor bounce the reading is the contact itself (sensors() reads it).
        self.delay: int = int(self.params["delay"])
        self.bounce: int = int(self.params["bounce"])
        self.contact = {"fsc": self.true_fsc(), "fso": self.true_fso()}
        self.reading = dict(self.contact)
        self.to_come: list[tuple[int, str, bool]] = []
        self.edges = {"fsc": 0, "fso": 0}  # contact changes so far (seeds `each` patterns)

    # -- sensors ---------------------------------------------------------------------------
    def true_fsc(self) -> bool:
        return self.pos <= self.band

    def true_fso(self) -> bool:
        return self.pos >= self.travel - self.band

    @property
    def switching(self) -> bool:
        """Whether the switches have dynamics of their own (a delay or a bounce)."""
        return bool(self.delay or self.bounce)

    def sensors(self) -> dict[str, bool]:
        if self.switching:
            fsc, fso = self.reading["fsc"], self.reading["fso"]
        else:
            fsc, fso = self.true_fsc(), self.true_fso()
        active = self.active_faults
        if "F1" in active:
            fsc = False
        if "F2" in active:
            fsc = True
        if "F3" in active:
            fso = False
        if "F4" in active:
            fso = True
        for sensor, (value, start, end) in self.glitches.items():
            if start <= self.t < end:
                if sensor == "fsc":
                    fsc = value
                else:
                    fso = value
        return {"fsc": fsc, "fso": fso}

    def read_sensors(self) -> Mapping[str, bool]:
        """The sensors right after an advance: the glide's, which that advance planned or
        moved in (the same mapping while it lasts: the plant then reuses what it made of
        it)."""
        glide = self._glide
        return glide[3] if glide is not None else self.sensors()

    def sense(self, t: int) -> Mapping[str, bool]:
        """:meth:`SimDevice.sense` taking the common case first: t inside the glide, so no
        fault due by t either (a glide ends at the next one: :meth:`_plan_glide`; one
        call, no step loop: most of the plant's reads, one a scan), exactly what
        :meth:`advance` would do there (:meth:`_glide_to`)."""
        glide = self._glide
        if glide is not None and t < glide[0]:
            step = t - self.t
            if step > 0:  # (_glide_to, written out: this is the plant's read at every scan)
                if glide[1]:
                    self.pos += glide[1] * step
                elif glide[2]:
                    self.stall_us += step
                self.t = t
            return glide[3]
        self.advance(t)
        return self.read_sensors()

    def touch(self) -> None:
        """The valve's physics was changed by hand (a test placing it): the glide it was in
        ends, the next advance steps in full."""
        self._glide = None

    def inject(self, code: str, at_us: int, duration_us: int | None = None,
               **options: Any) -> None:
        """A glide ends at the first fault due (:meth:`_plan_glide`): a new one may be due
        before, so the glide ends here (the next advance steps in full)."""
        super().inject(code, at_us, duration_us, **options)
        self._glide = None

    # -- physics ---------------------------------------------------------------------------
    def _drive(self) -> int:
        """Direction the motor pushes: +1 opening, -1 closing, 0 none."""
        if self.self_drive:
            return self.self_drive
        c, o = self.orders["C"], self.orders["O"]
        if o and not c:
            return 1
        if c and not o:
            return -1
        return 0

    def _can_move(self, drive: int) -> bool:
        if drive == 0 or self.jammed:
            return False
        return self.pos < self.travel if drive > 0 else self.pos > 0

    def _next_boundary(self, drive: int) -> int:
        """Time until something changes the dynamics (an end, a switch edge, a jam point)."""
        dt = _NEVER
        if self._can_move(drive):
            pos = self.pos
            for mark in self._marks:
                distance = (mark - pos) * drive
                if 0 < distance < dt:
                    dt = distance
            if "F13" in self.armed:
                distance = (self._block_point() - pos) * drive
                if 0 < distance < dt:
                    dt = distance
        elif drive and not self.stall_reported:
            dt = min(dt, self.params["stall_tolerance"] - self.stall_us + 1)
        for _, start, end in self.glitches.values():
            for edge in (start, end):
                if edge > self.t:
                    dt = min(dt, edge - self.t)
        if self.to_come:
            dt = min(dt, self.to_come[0][0] - self.t)
        return max(dt, 1)

    def _block_point(self) -> int:
        return int(self.travel * float(self.params["block_at"]))

    def _advance_to(self, t: int) -> None:
        glide = self._glide
        if glide is not None and t < glide[0]:
            self._glide_to(t, glide)
            return
        if not (self.glitches or self.self_drive or self.orders["C"] or self.orders["O"]
                or self.to_come):
            # At rest, no glitch under way: nothing moves, and _settle, already applied after
            # the last change (a move, new orders, a fault, a repair), would change nothing,
            # armed faults included (they wait for a position or orders that do not change
            # while at rest); only the time passes.
            self.t = max(self.t, t)
            self._glide = self._plan_glide()
            return
        while self.t < t:
            drive = self._drive()
            boundary = self._next_boundary(drive)
            step = min(t - self.t, boundary)
            if self._can_move(drive):
                self.pos = max(0, min(self.travel, self.pos + drive * step))
                self.stall_us = 0
                self.stall_reported = False
            elif drive:
                self.stall_us += step
            self.t += step
            if step == boundary:
                self._settle()
            # else: short of every mark, switch edge and stall limit (_next_boundary), so
            # everything _settle tests is as it was after the last change: nothing to do
        self._glide = self._plan_glide()

    def _plan_glide(self) -> Glide | None:
        """The glide from here: until the next boundary (_next_boundary), a step of the loop
        in _advance_to only moves the position by the drive, or runs the stall clock, and
        changes nothing _settle or the sensors read (the boundary is the first instant any
        of that changes, and it comes nearer by exactly the time that passes; where
        _next_boundary raised it to 1 µs, the glide holds at self.t only, where the loop does
        nothing either). None when a step in full would also reset the stall clock (the next
        one does, then glides). It also ends at the first fault due (sense need not look
        for one: the advance there activates it; the loop in _advance_to steps there, short
        of every boundary, as the glide would)."""
        drive = self._drive()
        can = self._can_move(drive)
        if can and (self.stall_us or self.stall_reported):
            return None
        end = self.t + self._next_boundary(drive)
        if self.pending and self.pending[0].at_us < end:
            end = self.pending[0].at_us
        return (end, drive if can else 0, bool(drive) and not can, self.sensors())

    def _glide_to(self, t: int, glide: Glide) -> None:
        """Move to `t` inside `glide`, as the loop in _advance_to would (one step short of
        the boundary: no _settle)."""
        step = t - self.t
        if step > 0:
            if glide[1]:
                self.pos += glide[1] * step
            elif glide[2]:
                self.stall_us += step
            self.t = t

    def _settle(self) -> None:
        """Apply what happens at the current instant: arrivals, armed faults, stalls."""
        self._glide = None  # (whatever changes here, the glide was planned without it)
        t = self.t
        if self.switching:
            self._switch(t)
        if self.true_fso() and not self.was_open:
            self.was_open = True
            self.opens += 1
        if self.true_fsc() and self.was_open:
            self.was_open = False
            self.closes += 1
            self.cycles += 1
        if self.self_drive and (self.pos == self.travel if self.self_drive > 0 else self.pos == 0):
            self.self_drive = 0
        if "F5" in self.armed and self.true_fsc():
            self.armed.discard("F5")
            self.jammed = True
        if "F6" in self.armed and self.true_fso():
            self.armed.discard("F6")
            self.jammed = True
        if "F13" in self.armed and self.pos == self._block_point():
            self.armed.discard("F13")
            self.jammed = True
        self._arm_glitches()
        at_rest = not self.orders["C"] and not self.orders["O"]
        if "F11" in self.armed and self.true_fsc() and at_rest and not self.jammed:
            self.armed.discard("F11")
            self.self_drive = 1
        if "F12" in self.armed and self.true_fso() and at_rest and not self.jammed:
            self.armed.discard("F12")
            self.self_drive = -1
        drive = self._drive()
        if drive and not self._can_move(drive) and not self.stall_reported and (
                self.stall_us > self.params["stall_tolerance"]):
            self.stall_reported = True
            if self.jammed:
                where = f"jammed at {100 * self.pos // self.travel}% open"
                self.record(t, "stall", True, f"motor driven against a jammed valve ({where}) "
                            f"for more than {seconds(self.params['stall_tolerance'])} s")
            else:
                stop = "open" if drive > 0 else "closed"
                order = "O" if drive > 0 else "C"
                self.record(t, "end_stop_overrun", True,
                            f"order {order} held against the {stop} end stop for more than "
                            f"{seconds(self.params['stall_tolerance'])} s")

    def _switch(self, t: int) -> None:
        """The switches at `t`: a change of a contact schedules its reading (`delay` late,
        then the bounce's flips); the changes due by `t` come out."""
        for sensor, now in (("fsc", self.true_fsc()), ("fso", self.true_fso())):
            if now != self.contact[sensor]:
                self.contact[sensor] = now
                self.edges[sensor] += 1
                start = t + self.delay
                # A change overtakes what its sensor still had to show from the last one.
                self.to_come = [e for e in self.to_come if e[1] != sensor or e[0] < start]
                self.to_come += [(start + offset, sensor, value)
                                 for offset, value in self._flips(sensor, now)]
                self.to_come.sort()
        to_come = self.to_come
        while to_come and to_come[0][0] <= t:
            _, sensor, value = to_come.pop(0)
            self.reading[sensor] = value

    def _flips(self, sensor: str, value: bool) -> list[tuple[int, bool]]:
        """(offset, reading) of one contact change: the new value at once, then, with a
        bounce, 1 to 3 flips back and forth drawn from the seed, settling at `bounce`."""
        if self.bounce < 2:  # (a flip needs room between the change and the settling)
            return [(0, value)]
        rank = self.edges[sensor] if self.params["bounce_pattern"] == "each" else int(value)
        draw = random.Random(f"{int(self.params['bounce_seed'])}:{sensor}:{int(value)}:{rank}")
        pairs = draw.randint(1, 3)
        inner = sorted(draw.randint(1, self.bounce - 1) for _ in range(2 * pairs - 1))
        offsets = [0, *inner, self.bounce]
        return [(offset, value if k % 2 == 0 else not value)
                for k, offset in enumerate(offsets)]

    def _arm_glitches(self) -> None:
        truth = {"fsc": self.true_fsc(), "fso": self.true_fso()}
        for code, sensor, value in (("F7", "fsc", True), ("F8", "fsc", False),
                                    ("F9", "fso", True), ("F10", "fso", False)):
            if code in self.armed and truth[sensor] != value:
                self.armed.discard(code)
                self.glitches[sensor] = (value, self.t, self.t + int(self.params["glitch"]))

    def _fault_activated(self, fault: PendingFault) -> None:
        code = fault.code
        if code in ("F5", "F6", "F7", "F8", "F9", "F10", "F11", "F12", "F13"):
            self.armed.add(code)
        if code == "F13" and self.band < self.pos < self.travel - self.band:
            self.armed.discard(code)
            self.jammed = True
        self._settle()

    def _repaired(self) -> None:
        self.jammed = False
        self.armed.clear()
        self.glitches.clear()
        self.self_drive = 0
        self.stall_us = 0
        self.stall_reported = False
        self._settle()

    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        both = self.orders["C"] and self.orders["O"]
        if both and not self.both_on:
            self.record(t, "both_orders", True, "open and close orders on together")
        self.both_on = both
        for port, value in changed.items():
            if value:
                continue
            target_reached = self.true_fso() if port == "O" else self.true_fsc()
            if not target_reached and not self.jammed:
                where = 100 * self.pos // self.travel
                self.record(t, "order_dropped_midway", False,
                            f"order {port} dropped with the valve {where}% open")
        self._settle()

    # -- reporting -------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        drive = self._drive()
        return {
            "position": round(100 * self.pos / self.travel, 1),
            "motion": drive if self._can_move(drive) else 0,
            "jammed": self.jammed,
        }

    def counters(self) -> dict[str, int]:
        return {"cycles": self.cycles, "opens": self.opens, "closes": self.closes}

    def state_key(self) -> Hashable:
        return (self.pos, self.jammed, self.self_drive, self.orders["C"], self.orders["O"])

    def counters_key(self) -> Hashable:
        return (self.cycles, self.opens, self.closes)
