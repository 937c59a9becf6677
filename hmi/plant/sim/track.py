"""Boxes on a straight line of conveyor segments: motion, accumulation, ends.

Positions are integer nanometres and speeds mm/s (= nm/µs), so a move over dt µs is exactly
`speed * dt` nm: no rounding, a run is repeatable bit for bit.

A :class:`Line` is a list of segments placed end to end along one axis (an entry conveyor then
a turntable; a left exit, the turntable, a right exit). Each segment has its own axis (a box's
`lo` is measured on it), pointing along the line's axis or against it. A box is carried by the
segment under its centre (its weight), at that segment's speed. Boxes never overlap: a box
that would run into the one ahead stops against it (accumulation, as on a real conveyor); two
touching boxes driven toward each other are reported as crushed. Each end of the line is a
`wall` (the box stops against it, reported), `open` (the box falls once its centre is past
the end) or an `exit` (the box leaves, delivered, once its front reaches the end).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hmi.plant.sim.boxes import Box

WALL, OPEN, EXIT = "wall", "open", "exit"


@dataclass(frozen=True)
class Segment:
    name: str
    start: int  # line coordinate of the segment's origin (nm)
    length: int  # nm
    direction: int  # +1: the segment's axis runs along the line's axis; -1: against it
    speed: int  # mm/s along the segment's own axis (negative: backwards), 0 when stopped
    low: int = field(init=False)  # the segment's extent in line coordinates
    high: int = field(init=False)
    velocity: int = field(init=False)  # speed along the line's axis (nm/µs)

    def __post_init__(self) -> None:  # computed once: a line is rebuilt only on a change
        low = self.start if self.direction > 0 else self.start - self.length
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", low + self.length)
        object.__setattr__(self, "velocity", self.speed * self.direction)

    def to_line(self, lo: int, length: int) -> int:
        """The line coordinate of the low end of a box at `lo` on this segment's axis."""
        return self.start + lo if self.direction > 0 else self.start - lo - length

    def from_line(self, line_lo: int, length: int) -> int:
        return line_lo - self.start if self.direction > 0 else self.start - line_lo - length


@dataclass(frozen=True)
class Line:
    segments: tuple[Segment, ...]  # in increasing line coordinates, end to end
    low_end: str = WALL
    high_end: str = WALL
    by_segment: dict[str, Segment] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "by_segment", {seg.name: seg for seg in self.segments})

    @property
    def moving(self) -> bool:
        return any(seg.speed for seg in self.segments)

    @property
    def low(self) -> int:
        return self.segments[0].low

    @property
    def high(self) -> int:
        return self.segments[-1].high

    def segment_at(self, x: int) -> Segment | None:
        for seg in self.segments:
            if seg.low <= x < seg.high:
                return seg
        return None

    def place(self, box: Box) -> int:
        """The line coordinate of a box's low end."""
        return self.by_segment[box.segment].to_line(box.lo, box.length)


@dataclass
class Outcome:
    """What happened on a line during one step; the owner turns it into plant events."""

    crushed: list[tuple[Box, Box]] = field(default_factory=list)  # touching, driven together
    walls: list[tuple[Box, str]] = field(default_factory=list)  # pressed against a wall end
    fallen: list[tuple[Box, str]] = field(default_factory=list)  # centre past an open end
    delivered: list[tuple[Box, str]] = field(default_factory=list)  # out through an exit


TOUCH = 1_000  # nm: boxes closer than this are touching


def advance(line: Line, boxes: list[Box], dt: int) -> Outcome:
    """Move the boxes on this line for dt µs; boxes that leave it are reported, not removed."""
    out = Outcome()
    if not boxes:
        return out
    placed = sorted(((line.place(b), b) for b in boxes), key=lambda item: item[0])
    lows = [x for x, _ in placed]
    items = [b for _, b in placed]
    n = len(items)
    velocity = []
    for x, box in placed:
        seg = line.segment_at(x + box.length // 2)
        velocity.append(seg.velocity if seg is not None else 0)
    for i in range(n - 1):  # touching boxes driven toward each other cannot move
        if velocity[i] > 0 > velocity[i + 1] and \
                lows[i + 1] - (lows[i] + items[i].length) <= TOUCH:
            out.crushed.append((items[i], items[i + 1]))
            velocity[i] = velocity[i + 1] = 0
    new = list(lows)
    for i in range(n):  # boxes moving down the axis, from the lowest up
        v = velocity[i]
        if v >= 0:
            continue
        target = lows[i] + v * dt
        if i == 0:
            if line.low_end == WALL and target < line.low:
                target = line.low
                out.walls.append((items[i], "low"))
        else:
            below = new[i - 1] + items[i - 1].length if velocity[i - 1] <= 0 else \
                lows[i - 1] + items[i - 1].length
            target = max(target, below)
        new[i] = target
    for i in range(n - 1, -1, -1):  # boxes moving up the axis, from the highest down
        v = velocity[i]
        if v <= 0:
            continue
        target = lows[i] + v * dt
        if i == n - 1:
            if line.high_end == WALL and target + items[i].length > line.high:
                target = line.high - items[i].length
                out.walls.append((items[i], "high"))
        else:
            target = min(target, new[i + 1] - items[i].length)
        new[i] = max(target, lows[i])
    for x, box in zip(new, items, strict=True):
        centre = x + box.length // 2
        if line.high_end == EXIT and x + box.length >= line.high:
            out.delivered.append((box, "high"))
            continue
        if line.low_end == EXIT and x <= line.low:
            out.delivered.append((box, "low"))
            continue
        seg = line.segment_at(centre)
        if seg is None:
            out.fallen.append((box, "high" if centre >= line.high else "low"))
            continue
        box.segment = seg.name
        box.lo = seg.from_line(x, box.length)
    return out


def covered(line: Line, boxes: list[Box], x: int) -> bool:
    """Whether a light beam across the line at coordinate x is interrupted by a box."""
    for box in boxes:
        lo = line.place(box)
        if lo <= x <= lo + box.length:
            return True
    return False


NEVER = 1 << 62  # a number of steps larger than any run


def beam_steps(lo: int, hi: int, x: int, d: int) -> int:
    """The first step after which a box spanning [lo, hi] and moving d a step covers a light
    beam at x otherwise than now (covered: lo <= x <= hi, as :func:`covered` reads it);
    NEVER when it never will. The cells' glides (sorter, palletizer) stop before it."""
    if d > 0:
        if lo <= x <= hi:
            return (x - lo) // d + 1
        return -(-(x - hi) // d) if x > hi else NEVER
    if d < 0:
        if lo <= x <= hi:
            return (hi - x) // -d + 1
        return -(-(lo - x) // -d) if x < lo else NEVER
    return NEVER
