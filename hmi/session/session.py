"""Driving the engine: virtual-time runs for headless use, and the one command interface.

:class:`Controller` is what the UI and the headless commands talk to. It owns the run state
(running, paused, stepping) and forwards engine commands, so pause/step/manual/reset all
enter through :meth:`Controller.command`. It never sleeps: the live app paces it from a
worker thread; headless runs call :meth:`Controller.run_for` in virtual time.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Callable
from dataclasses import dataclass

from hmi.engine.commands import (
    Command,
    CommandResult,
    Pause,
    Resume,
    SetSpeed,
    StepScans,
    describe,
)
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.plant.base import PlantError


def settle_memory() -> None:
    """Move everything built so far (project, compiled expressions, UI) out of the garbage
    collector's sight: the scan creates no reference cycles, and collections that re-traverse
    those long-lived objects are what makes a scan's worst case several times its median.
    """
    gc.collect()
    gc.freeze()


@dataclass
class RunState:
    running: bool = True
    speed: float | None = 1.0  # None: as fast as possible
    pending_steps: int = 0

    @property
    def label(self) -> str:
        if self.pending_steps:
            return "stepping"
        return "running" if self.running else "paused"


Listener = Callable[[Command, CommandResult, Snapshot | None], None]


class Controller:
    """The engine plus its run state; thread-safe so a UI thread can send commands."""

    def __init__(self, engine: Engine, period_us: int | None = None,
                 clock: Callable[[], int] | None = None):
        self.engine = engine
        self.period_us = period_us or engine.project.scan_period_us
        # A real plant runs on real time: each scan's time comes from `clock` (see
        # hmi.engine.live.WallClock) instead of advancing by one period per scan.
        self.clock = clock
        self.state = RunState()
        self.lock = threading.RLock()
        self.listeners: list[Listener] = []
        self.scan_listeners: list[Callable[[Snapshot], None]] = []
        # Told of each scan overrun (a real-time runner more than a period late), for the
        # journal; called from the scan thread with the runner's overrun count.
        self.overrun_listeners: list[Callable[[int], None]] = []

    @property
    def next_time(self) -> int:
        if self.clock is not None:
            return self.clock()
        return 0 if not self.engine.scan else self.engine.now + self.period_us

    def command(self, command: Command) -> CommandResult:
        with self.lock:
            match command:
                case Pause():
                    self.state.running = False
                    result = CommandResult.ok("paused" + self._park_real_plant())
                case Resume():
                    self.state.running = True
                    self.state.pending_steps = 0
                    result = CommandResult.ok("running")
                case StepScans(count=n):
                    if self.engine.drives_real_plant:
                        result = CommandResult.refused(
                            "stepping would drive a real plant for a scan and leave it so; "
                            "not available on a real plant (pause holds it safe)")
                    elif n < 1:
                        result = CommandResult.refused("step count must be at least 1")
                    else:
                        self.state.running = False
                        for _ in range(n):
                            self.scan_once()
                        result = CommandResult.ok(f"stepped {n} scan{'s' if n > 1 else ''}, "
                                                  f"now scan {self.engine.scan}")
                case SetSpeed(factor=factor):
                    self.state.speed = factor
                    result = CommandResult.ok(describe(command))
                case _:
                    result = self.engine.apply(command)
            for listener in self.listeners:
                listener(command, result, self.engine.last)
            return result

    def _park_real_plant(self) -> str:
        """A paused PLC must not leave a real plant driven: write the safe vector once."""
        engine = self.engine
        plant = engine.plant
        if not self.engine.drives_real_plant or not engine.started:
            return ""
        try:
            plant.write(engine.now, dict(zip(engine.layout.outputs, engine.safe_vector,
                                             strict=True)))
        except PlantError as exc:
            return f"; the safe outputs could not be written ({exc})"
        return "; real plant: outputs written safe while paused"

    def scan_if_running(self) -> Snapshot | None:
        """One scan unless paused meanwhile (checked under the lock, so no scan follows a
        pause: a paused real plant keeps the safe outputs the pause wrote)."""
        with self.lock:
            return self.scan_once() if self.state.running else None

    def scan_once(self) -> Snapshot:
        with self.lock:
            snapshot = self.engine.step(self.next_time)
            for listener in self.scan_listeners:
                listener(snapshot)
            return snapshot

    def run_for(self, duration_us: int, on_scan: Callable[[Snapshot], None] | None = None
                ) -> Snapshot:
        """Run scans in virtual time from now until `duration_us` more has elapsed."""
        end = self.next_time + duration_us
        snapshot = self.engine.last
        while self.next_time <= end:
            snapshot = self.scan_once()
            if on_scan is not None:
                on_scan(snapshot)
        assert snapshot is not None
        return snapshot
