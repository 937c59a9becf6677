"""Two engines on one project, stepped together: the compiled scan and the stage objects
(the reference interpreter, its filter searching every correction afresh). Every scan's
snapshots must agree (tests/test_compiled_scan.comparable), so a test written on what one
engine does checks the other as well."""
from __future__ import annotations

from typing import Any

from hmi.engine.commands import Command, CommandResult
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.plant.sim.plant import SimPlant
from hmi.project.model import Project
from tests.test_compiled_scan import comparable

S = 1_000_000  # µs in a second


class Twins:
    """The compiled engine and the stage objects, stepped together and compared. `snaps`
    keeps every snapshot of the compiled one, in order."""

    def __init__(self, project: Project, **kwargs: Any):
        self.engines = [Engine(project, SimPlant(project), compiled=flag, **kwargs)
                        for flag in (True, False)]
        self.engines[1].safety_filter.remember = False
        self.period = project.scan_period_us
        self.k = 0
        self.snaps: list[Snapshot] = []

    def set_input(self, name: str, value: bool) -> None:
        for e in self.engines:
            e.plant.set_input(name, value)

    def apply(self, command: Command) -> CommandResult:
        results = [e.apply(command) for e in self.engines]
        assert results[0] == results[1]
        return results[0]

    def scan(self) -> Snapshot:
        fast, reference = (e.step(self.k * self.period) for e in self.engines)
        assert comparable(fast) == comparable(reference), f"scan {self.k}"
        self.k += 1
        self.snaps.append(fast)
        return fast

    def run(self, seconds: float) -> list[Snapshot]:
        """The scans of `seconds` more virtual time, in order."""
        return [self.scan() for _ in range(round(seconds * S) // self.period)]
