"""Boxes (the items a cell handles) and the deterministic source that feeds them.

Arrivals follow a schedule fixed by a seed: box k is due at
`first + sum(interval_1..interval_k)`, each interval drawn uniformly (in whole milliseconds)
between `interval_min` and `interval_max`, and each box is high with probability `p_high`,
all from one `random.Random(seed)`. The schedule does not depend on the cell: a box due while
the entry is still occupied waits (it is counted as queued) and is placed as soon as there is
room, so two runs with the same parameters see exactly the same boxes at the same times.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

MM = 1_000_000  # nanometres per millimetre: positions are integer nm, speeds mm/s = nm/µs


@dataclass
class Box:
    ident: int
    length: int  # nm, along the direction of travel
    high: bool  # a high box (seen by the high height sensor) or a low one
    segment: str  # the conveyor or table carrying it (the one under its centre)
    lo: int  # nm: its end nearest the segment's origin, on the segment's own axis
    due_us: int = 0  # when the schedule made it due

    @property
    def kind(self) -> str:
        return "high" if self.high else "low"


class BoxSource:
    """The schedule of arriving boxes; the cell asks `due(t)` and places them when it can."""

    def __init__(self, seed: int, first_us: int, interval_min_us: int, interval_max_us: int,
                 p_high: float):
        self.rng = random.Random(seed)
        self.interval = (interval_min_us // 1000, max(interval_min_us, interval_max_us) // 1000)
        self.p_high = p_high
        self.next_due = first_us
        self.next_high = self._draw_height()
        self.count = 0
        self.queued: list[tuple[int, bool]] = []  # (due time, high) of boxes waiting for room

    def _draw_height(self) -> bool:
        return self.rng.random() < self.p_high

    def collect(self, t: int) -> None:
        """Move every box due by t into the queue (in order)."""
        while self.next_due <= t:
            self.queued.append((self.next_due, self.next_high))
            self.next_due += 1000 * self.rng.randint(*self.interval)
            self.next_high = self._draw_height()

    def pop(self) -> tuple[int, bool, int]:
        """The oldest queued box: (identifier, high, due time)."""
        due, high = self.queued.pop(0)
        self.count += 1
        return self.count, high, due
