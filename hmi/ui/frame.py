"""One frame of the display: a snapshot plus the few things around it that the UI shows.

The app builds a frame at most ~20 times a second and hands it down to every panel; a panel
only reads its frame, never the engine, so the whole screen shows one consistent scan.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from hmi.engine.snapshot import Snapshot
from hmi.plant.sim import Injection


@dataclass(frozen=True)
class InjectedFault:
    """A fault the operator scheduled in the simulated plant, as the UI remembers it."""

    injection: Injection
    description: str


@dataclass(frozen=True, eq=False)
class Frame:
    snapshot: Snapshot
    run: str  # "running", "paused" or "stepping"
    speed: float | None  # 1.0 real time, 10.0, None as fast as possible
    live: bool  # scans paced by the wall clock (False: a test or a screenshot drives them)
    project: str
    show_measured: bool = True  # False hides wall-clock figures (snapshot tests)
    overruns: int = 0  # scans that fell more than a period behind (live only)
    changed: Mapping[str, str] = field(default_factory=dict)  # output -> why it differs
    injected: tuple[InjectedFault, ...] = ()
    free_inputs: tuple[str, ...] = ()  # inputs no simulated device drives: push buttons
    damage_count: int = 0  # damaging plant events seen since the app started

    @property
    def simulated(self) -> bool:
        return self.snapshot.plant.kind == "sim"

    @property
    def manual(self) -> bool:
        return self.snapshot.mode == "manual"
