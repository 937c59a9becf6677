"""IEC 61131-3 on-delay (TON) and off-delay (TOF) timers, in integer microseconds."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TimerState:
    name: str
    q: bool
    elapsed_us: int  # ET: time counted towards the preset (0 when idle)
    preset_us: int


class TimerRuntime:
    """One timer's state: Q, and since when IN rose (TON) or fell (TOF). The rule that
    updates it once per scan is hmi.program.timers' lowering, the one both the compiled scan
    and the reference evaluator run."""

    __slots__ = ("kind", "name", "preset", "q", "since")

    def __init__(self, name: str, kind: str, preset_us: int):
        self.name = name
        self.kind = kind
        self.preset = preset_us
        self.q = False
        self.since: int | None = None  # TON: IN rose at; TOF: IN fell at

    def elapsed(self, now: int) -> int:
        if self.since is None:
            return 0
        return min(now - self.since, self.preset)

    def state(self, now: int) -> TimerState:
        return TimerState(self.name, self.q, self.elapsed(now), self.preset)
