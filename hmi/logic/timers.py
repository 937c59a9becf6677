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
    """One timer. `update(inp, now)` is called once per scan and returns Q."""

    __slots__ = ("kind", "name", "preset", "q", "since")

    def __init__(self, name: str, kind: str, preset_us: int):
        self.name = name
        self.kind = kind
        self.preset = preset_us
        self.q = False
        self.since: int | None = None  # TON: IN rose at; TOF: IN fell at

    def update(self, inp: bool, now: int) -> bool:
        if self.kind == "TON":
            if inp:
                if self.since is None:
                    self.since = now
                self.q = now - self.since >= self.preset
            else:
                self.since = None
                self.q = False
        else:  # TOF
            if inp:
                self.since = None
                self.q = True
            elif self.q:
                if self.since is None:
                    self.since = now
                if now - self.since >= self.preset:
                    self.q = False
                    self.since = None
        return self.q

    def elapsed(self, now: int) -> int:
        if self.since is None:
            return 0
        return min(now - self.since, self.preset)

    def state(self, now: int) -> TimerState:
        return TimerState(self.name, self.q, self.elapsed(now), self.preset)
