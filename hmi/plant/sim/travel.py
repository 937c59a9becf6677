"""A two-way actuator between two end positions: the turntable's rotation, a pusher, a
sliding plate, a clamp, an elevator.

Like the valve, the position is counted in microseconds of motor time (0 = the low end,
`travel` = the high end), so the physics is exact integer arithmetic. The owner (a cell
device) decides which way it is driven each step; this class moves it, says where it is, and
counts how long an order has been held without motion (against an end stop, or while the
actuator is jammed) so the owner can record the damage once it lasts beyond a tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Travel:
    travel: int  # µs from one end to the other
    band: int  # an end switch is made within this much travel of its end
    pos: int = 0
    jammed: bool = False  # a fault: the actuator does not move whatever it is ordered
    stall_us: int = 0  # how long the current order has been held without motion
    stall_reported: bool = False

    @property
    def at_low(self) -> bool:
        return self.pos <= self.band

    @property
    def at_high(self) -> bool:
        return self.pos >= self.travel - self.band

    @property
    def percent(self) -> float:
        return round(100 * self.pos / self.travel, 1)

    def can_move(self, drive: int) -> bool:
        if drive == 0 or self.jammed:
            return False
        return self.pos < self.travel if drive > 0 else self.pos > 0

    def step(self, dt: int, drive: int, limit: int | None = None) -> int:
        """Move for dt µs in direction `drive` (+1, -1, 0); return the distance moved.

        `limit` is an obstacle the actuator cannot pass in the direction it is driven (the
        elevator's load meeting the plate); reaching it counts as held without motion.
        """
        if not self.can_move(drive):
            if drive:
                self.stall_us += dt
            return 0
        end = self.travel if drive > 0 else 0
        if limit is not None:
            end = min(end, limit) if drive > 0 else max(end, limit)
        if (end - self.pos) * drive <= 0:  # already against the obstacle
            self.stall_us += dt
            return 0
        target = self.pos + drive * dt
        target = min(target, end) if drive > 0 else max(target, end)
        moved = abs(target - self.pos)
        self.pos = target
        if moved < dt:
            self.stall_us += dt - moved
        else:
            self.stall_us = 0
            self.stall_reported = False
        return moved

    def release(self) -> None:
        """The order dropped: the stall count starts again at the next order."""
        self.stall_us = 0
        self.stall_reported = False

    def stalled_beyond(self, tolerance: int) -> bool:
        """True once per stall: the order has been held without motion beyond `tolerance`."""
        if self.stall_us > tolerance and not self.stall_reported:
            self.stall_reported = True
            return True
        return False


def direction(forward: bool, backward: bool) -> int:
    """+1, -1, or 0 (no order, or both orders: a motor driven both ways does not move)."""
    if forward and not backward:
        return 1
    if backward and not forward:
        return -1
    return 0


def free_steps(travel: Travel, drive: int, dt: int, marks: tuple[int, ...], never: int) -> int:
    """How many full steps of `dt` a travel moving `drive` (it can move) makes before reaching
    a position where anything about it changes: its end switches (`band`), its ends, or
    `marks` (each the first position of a "pos >= mark" test: a transfer point, half the
    stroke...); `never` when nothing is ahead. The cells' glides stop before it."""
    pos = travel.pos
    bounds = (travel.band + 1, travel.travel - travel.band, travel.travel, 1, *marks)
    if drive > 0:
        return min(((b - 1 - pos) // dt for b in bounds if b > pos), default=never)
    return min(((pos - b) // dt for b in bounds if b <= pos), default=never)
