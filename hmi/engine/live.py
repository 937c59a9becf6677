"""Running the engine against the wall clock, in a thread of its own.

The scan thread never waits for a UI: it steps the controller on schedule and leaves the
latest snapshot in the engine, where a UI reads it at its own pace. Lateness of each scan
against its schedule is kept as jitter samples for `plchmi bench ui`.
"""

from __future__ import annotations

import threading
import time
from collections import deque

from hmi.engine.runner import Controller, settle_memory


class LiveRunner:
    def __init__(self, controller: Controller, keep_jitter: int = 100_000):
        self.controller = controller
        self.jitter_us: deque[float] = deque(maxlen=keep_jitter)
        self.overruns = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="plchmi-scan", daemon=True)

    def start(self) -> None:
        settle_memory()
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _loop(self) -> None:
        controller = self.controller
        period_s = controller.period_us / 1e6
        next_wall = time.perf_counter()
        while not self._stop.is_set():
            state = controller.state
            if not state.running:
                self._stop.wait(0.02)
                next_wall = time.perf_counter()
                continue
            speed = state.speed
            now = time.perf_counter()
            if speed is not None:
                lateness = now - next_wall
                if lateness < 0:
                    self._stop.wait(-lateness)
                    now = time.perf_counter()
                    lateness = now - next_wall
                self.jitter_us.append(lateness * 1e6)
            controller.scan_once()
            if speed is None:
                next_wall = time.perf_counter()
                continue
            next_wall += period_s / speed
            if time.perf_counter() > next_wall + period_s:
                # More than a whole period late: count it and re-anchor rather than burst.
                self.overruns += 1
                next_wall = time.perf_counter()
