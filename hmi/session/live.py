"""Running the engine against the wall clock, in a thread of its own.

The scan thread never waits for a UI: it steps the session on schedule and leaves the
latest snapshot in the engine, where a UI reads it at its own pace. Lateness of each scan
against its schedule is kept as jitter samples for `plchmi bench ui`.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable

from hmi.session.session import Session, settle_memory
from hmi.session.view import CellView


class Lateness:
    """How late each scan started, as a histogram (10 µs bins to 10 ms, then 1 ms bins to
    1 s): constant memory and a constant cost per scan, however long the run, and its
    percentiles read at any time without sorting anything (a sort of a long run's samples
    would hold the interpreter for milliseconds, in the scans' process)."""

    FINE_US, FINE_BINS, COARSE_US, COARSE_BINS = 10, 1000, 1000, 990

    def __init__(self) -> None:
        self.bins = [0] * (self.FINE_BINS + self.COARSE_BINS + 1)
        self.count = 0
        self.most = 0.0

    def add(self, us: float) -> None:
        fine = self.FINE_US * self.FINE_BINS
        if us < fine:
            index = max(0, int(us // self.FINE_US))
        else:
            index = min(self.FINE_BINS + int((us - fine) // self.COARSE_US),
                        len(self.bins) - 1)
        self.bins[index] += 1
        self.count += 1
        if us > self.most:
            self.most = us

    def percentile(self, q: float) -> float:
        """The upper edge of the bin holding the q-quantile (µs); 0 with no sample."""
        if not self.count:
            return 0.0
        wanted = q * self.count
        seen = 0
        for index, n in enumerate(self.bins):
            seen += n
            if seen >= wanted and n:
                if index < self.FINE_BINS:
                    return float((index + 1) * self.FINE_US)
                return float(self.FINE_US * self.FINE_BINS
                             + (index - self.FINE_BINS + 1) * self.COARSE_US)
        return self.most


BENCH_JITTER = 100_000  # scans whose lateness a bench keeps, one by one
REALTIME_PRIORITY = 10  # SCHED_FIFO priority of a runtime's scan thread (1-99)


class LiveRunner:
    """Scans on the wall clock in a thread of its own.

    `realtime`: the scan thread asks the kernel for SCHED_FIFO (Linux soft PLCs run their
    scan at a real-time priority the same way: a runnable scan thread then takes its core
    from any ordinary thread); refused (no privilege), it says so in :attr:`realtime_state`
    and scans at normal priority. Running as fast as possible (a simulation's ``max``
    speed), it gives the priority back: a thread that never sleeps must not hold a core
    from everything else."""

    def __init__(self, session: Session, keep_jitter: int = 0,
                 realtime: bool = False):
        self.session = session
        self.realtime = realtime
        self.realtime_state = "normal priority (not asked)"
        # None until the scan thread sets its own policy (it may inherit a real-time one)
        self._realtime_now: bool | None = None
        self.realtime_known = threading.Event()  # realtime_state says what happened
        # Each scan's lateness, the last `keep_jitter` (the benches' samples). None by default:
        # a runtime's figures are `lateness`, in constant memory (100,000 kept samples were
        # 3 MB that a runtime grew by over its first 17 minutes).
        self.jitter_us: deque[float] = deque(maxlen=keep_jitter)
        self.lateness = Lateness()
        self.overruns = 0
        # Why the scan thread died, if it did (a scan listener failed): whoever runs it must
        # end the run as an abnormal end, since nothing scans any more.
        self.error: BaseException | None = None
        self.error_traceback = ""
        self.started = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="plchmi-scan", daemon=True)

    @property
    def thread_id(self) -> int | None:
        """The scan thread's id for the kernel (None before it starts)."""
        return self._thread.native_id

    def start(self) -> None:
        settle_memory()
        arm_search_deadline(self.session)
        self._thread.start()
        self.started = True

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _loop(self) -> None:
        try:
            self._scan_loop()
        except Exception as exc:
            self.error = exc
            self.error_traceback = traceback.format_exc()

    def _priority(self, wanted: bool) -> None:
        """Ask for SCHED_FIFO (or give it back), from the scan thread itself."""
        if wanted == self._realtime_now:
            return
        try:
            if wanted:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
                self.realtime_state = f"SCHED_FIFO {REALTIME_PRIORITY}"
            else:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
                self.realtime_state = "normal priority while running as fast as possible"
            self._realtime_now = wanted
        except (OSError, AttributeError) as exc:  # no privilege, or not Linux
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            self.realtime_state = f"normal priority: SCHED_FIFO refused ({reason})"
            with contextlib.suppress(OSError, AttributeError):  # a policy inherited is given back
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            self._realtime_now = False
            self.realtime = False  # not asked again at every scan
        finally:
            self.realtime_known.set()

    def _scan_loop(self) -> None:
        session = self.session
        period_s = session.period_us / 1e6
        next_wall = time.perf_counter()
        if not self.realtime:
            self.realtime_known.set()
        while not self._stop.is_set():
            state = session.state
            if self.realtime:
                self._priority(state.speed is not None)
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
                self.lateness.add(lateness * 1e6)
            session.scan_if_running()
            if speed is None:
                next_wall = time.perf_counter()
                continue
            next_wall += period_s / speed
            if time.perf_counter() > next_wall + period_s:
                # More than a whole period late: count it and re-anchor rather than burst.
                self.overruns += 1
                for listener in session.overrun_listeners:
                    listener(self.overruns)
                next_wall = time.perf_counter()


def arm_search_deadline(session: Session) -> None:
    """Live runs only: the corrector's search also stops at half the scan period of wall time.

    The search's own budget is in steps (deterministic); on a machine slower or busier than
    the one the budget was chosen on, this net keeps the scan on time. A headless run never
    arms it, so it cannot change a trace (docs/filter.md, "Budget")."""
    session.engine.limit_search_time(session.period_us / 2)


class WallClock:
    """Scan times for a real plant: whole microseconds of monotonic time since the first call.

    Strictly increasing, so two scans never share a time. The engine itself never reads a
    clock; a Session given this clock stamps each scan with the real time it started.
    """

    def __init__(self) -> None:
        self._t0: int | None = None
        self._last = -1

    def __call__(self) -> int:
        now = time.monotonic_ns() // 1000
        if self._t0 is None:
            self._t0 = now
        t = max(now - self._t0, self._last + 1)
        self._last = t
        return t


def run_live_for(session: Session, duration_us: int,
                 on_scan: Callable[[CellView], bool | None] | None = None) -> LiveRunner:
    """Run scans paced by the wall clock until the scan time reaches `duration_us`, or until
    `on_scan` returns True (a failure that ends the run early).

    A headless run against a real plant: the same LiveRunner as the HMI, without a UI.
    Returns the (stopped) runner, whose `overruns` and `lateness` the caller may report.
    """
    done = threading.Event()

    def listener(cell: CellView) -> None:
        if done.is_set():
            return
        if on_scan is not None and on_scan(cell):
            done.set()
        if cell.snapshot.time_us >= duration_us:
            done.set()

    session.scan_listeners.append(listener)
    runner = LiveRunner(session)
    runner.start()
    try:
        while not done.wait(0.1):
            if not runner.alive:
                raise RuntimeError(f"the scan thread stopped unexpectedly: {runner.error!r}"
                                   ) from runner.error
    finally:
        runner.stop()
        session.scan_listeners.remove(listener)
    return runner
