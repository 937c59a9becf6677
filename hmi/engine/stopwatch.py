"""The stopwatch automaton of one interruptible task (002 Fig. 3 and 4.5), in integer µs.

Locations (002): ``waiting`` (l1), ``executing`` (l2), ``interrupted`` (l3), ``faulty`` (l4).
Stopwatch ``x`` is the time since the task started; it runs in executing and interrupted.
Stopwatch ``y`` is the effective work; it runs in executing only (frozen while interrupted).

A correct run ends with ``y`` in [alpha, beta] and ``x`` in [alpha, gamma) (002 Property 1:
``x == gamma`` is already too late). The fault is raised as soon as no continuation can
satisfy that any more, which gives these rules, checked at every scan:

* ``cannot_finish`` — the task still needs ``alpha - y`` of work, which cannot end before
  gamma: ``x + (alpha - y) >= gamma`` with ``y < alpha``. ``x - y`` only grows while the task
  is interrupted, so this first holds during an interruption (002 §4, location L8:
  ``(delta_x2 + x_T2) - delta_y2 >= 2``) or at the very scan it resumes;
* ``deadline`` — the task has done its minimum work but is still running when ``x`` reaches
  gamma (``y >= alpha`` and ``x >= gamma``);
* ``overrun`` — ``y > beta``, or the task is still executing with ``y == beta`` after this
  scan's events: it did not end with ``y <= beta`` and any later end follows more work, so
  whenever it ends, ``y > beta``;
* at the end: ``late_end`` (``x >= gamma``), ``overrun`` (``y > beta``), ``too_fast``
  (``y < alpha``).

The first three are the complement of the acceptable time space of 002 Fig. 4.4 in l2/l3
(``x + max(0, alpha - y) < gamma`` and ``y <= beta``), sampled at scans. Nothing earlier is
possible without false alarms: while they are false, ending with ``y`` in [alpha, beta]
before gamma is still reachable.

The automaton is driven by scans: :meth:`TaskAutomaton.step` receives the scan's time and the
four observations. The location entered at a scan holds until the next scan, so the
stopwatches first advance by the elapsed time in the location held since the previous scan,
then the scan's observations are applied, then the rules are checked on the exact values.
When the plant's events fall on scan instants, ``x`` and ``y`` are exact; otherwise an
event is dated at the first scan that sees it (at most one period late).

A detection is latched (location ``faulty``) until :meth:`TaskAutomaton.reset`. While it is
latched the automaton keeps tracking the task, so that a reset knows whether the task is
still hopeless, and so that the plain watchdog used for comparison keeps running.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from hmi.program.evaluate import evaluator
from hmi.program.ir import Local
from hmi.program.monitors import VERDICTS, lower_task
from hmi.timefmt import seconds as _s


class Phase(Enum):
    """What the task is doing, as observed (independent of any latched fault)."""

    IDLE = "waiting"
    RUNNING = "executing"
    SUSPENDED = "interrupted"


FAULTY = "faulty"

RULES = {
    "cannot_finish": "cannot end in time: still needs alpha - y of work, x + (alpha - y) >= "
                     "gamma",
    "deadline": "still running when x reached gamma",
    "overrun": "effective work y goes beyond beta",
    "late_end": "ended with x >= gamma",
    "too_fast": "ended with y < alpha (too fast)",
}


@dataclass(frozen=True)
class Window:
    """Normal duration [alpha, beta] and acceptable duration [alpha, gamma], in µs."""

    alpha_us: int
    beta_us: int
    gamma_us: int

    def __post_init__(self) -> None:
        if not 0 <= self.alpha_us <= self.beta_us < self.gamma_us:
            raise ValueError(f"need 0 <= alpha <= beta < gamma, got {self}")


@dataclass(frozen=True)
class Detection:
    """Why and when a task was found faulty, with the stopwatch values at that scan."""

    rule: str  # a key of RULES
    time_us: int
    scan: int
    x_us: int
    y_us: int
    attempt: int  # which start of the task (1 = the first)
    attempt_start_us: int

    @property
    def reason(self) -> str:
        return RULES[self.rule]

    def explain(self, window: Window) -> str:
        """The rule with this detection's numbers, in seconds."""
        a, b, g = window.alpha_us, window.beta_us, window.gamma_us
        x, y = self.x_us, self.y_us
        if self.rule == "cannot_finish":
            return (f"cannot end in time: still needs alpha - y = {_s(a - y)} s of work, so "
                    f"it ends at x >= {_s(x + a - y)} s, not before gamma = {_s(g)} s")
        if self.rule == "deadline":
            return f"still running when x reached gamma = {_s(g)} s"
        if self.rule == "overrun":
            return (f"effective work y = {_s(y)} s and still working: it ends with y > beta = "
                    f"{_s(b)} s")
        if self.rule == "late_end":
            return f"ended at x = {_s(x)} s, not before gamma = {_s(g)} s"
        return f"ended after y = {_s(y)} s of work, less than alpha = {_s(a)} s (too fast)"


@dataclass(frozen=True)
class WatchdogTrip:
    """When a plain watchdog (fault when x reaches gamma) fired on the same attempt."""

    time_us: int
    scan: int
    x_us: int
    attempt: int


class Watchdog:
    """The usual alternative to a stopwatch monitor: a timer started with the task that
    trips when the task has not ended once gamma has elapsed. Kept beside each monitor to
    measure how much earlier the monitor is on the same run; it never raises a label."""

    def __init__(self, gamma_us: int):
        self.gamma_us = gamma_us
        self.last: WatchdogTrip | None = None
        self._armed = False

    def start(self) -> None:
        self._armed = True

    def stop(self) -> None:
        """The attempt was abandoned: nothing to trip on."""
        self._armed = False

    def trip(self, now: int, scan: int, x_us: int, attempt: int) -> None:
        """The armed watchdog saw x reach gamma (hmi.program.monitors: the scan program
        watches it at every scan of an attempt, and disarms it at the attempt's end)."""
        self.last = WatchdogTrip(now, scan, x_us, attempt)
        self._armed = False


class TaskAutomaton:
    """One task's stopwatch automaton; pure logic, no engine, no expressions."""

    def __init__(self, window: Window):
        self.window = window
        self.phase = Phase.IDLE
        self.x_us = 0
        self.y_us = 0
        self.last_us: int | None = None
        self.attempt = 0
        self.attempt_start_us = 0
        self.attempt_fault: Detection | None = None  # the current/last attempt's verdict
        self.latched: Detection | None = None  # what the label shows until a reset
        self.last_detection: Detection | None = None
        self.faults = 0  # attempts found faulty
        self.completed = 0  # attempts ended inside the acceptable window
        self.watchdog = Watchdog(window.gamma_us)
        self._program: Callable[..., None] | None = None  # step's, built at its first call
        # Changes of what the operator sees apart from the stopwatches (phase, attempt,
        # detections, watchdog trips, counts, the latch): Snapshot.monitor_marks sums them.
        self.changes = 0

    # -- what the operator sees -------------------------------------------------------------
    @property
    def location(self) -> str:
        return FAULTY if self.latched is not None else self.phase.value

    @property
    def running(self) -> bool:
        return self.phase is not Phase.IDLE

    # -- one scan ---------------------------------------------------------------------------
    def step(self, now: int, scan: int, start: bool, end: bool, suspend: bool,
             resume: bool) -> Detection | None:
        """Advance to `now` and apply this scan's observations; return a new detection.

        `suspend` is looked at while executing and `resume` while interrupted, so a level
        signal "task interrupted" is passed as (level, not level) and a pair of events as
        they are. The rules are hmi.program.monitors' lowering, the one the engine's scan
        runs too, here through the program's evaluator."""
        program = self._program
        if program is None:
            lowered = lower_task(
                self, (self.window.alpha_us, self.window.beta_us, self.window.gamma_us),
                (Phase.IDLE, Phase.RUNNING, Phase.SUSPENDED),
                Local("start"), Local("end"), Local("suspend"), Local("resume"))
            program = self._program = evaluator(lowered, {}, {})
        latched = self.latched
        program([], (), now, scan, start=start, end=end, suspend=suspend, resume=resume)
        return self.latched if self.latched is not latched else None

    def detect(self, verdict: int, now: int, scan: int) -> None:
        """The attempt in progress broke a rule (a verdict of hmi.program.monitors): the
        evidence, counted, and latched unless a fault is latched already (the label keeps
        its first evidence)."""
        detection = Detection(VERDICTS[verdict - 1], now, scan, self.x_us, self.y_us,
                              self.attempt, self.attempt_start_us)
        self.attempt_fault = detection
        self.last_detection = detection
        self.faults += 1
        self.changes += 1
        if self.latched is None:
            self.latched = detection

    def abandon(self) -> bool:
        """Forget the attempt in progress (True if there was one): a recovery is about to
        move the cell in ways no task describes, and the program restarts from its initial
        steps after it. The next start begins a new attempt; a latched label stays until a
        fault reset, which can release it now that no condemned attempt runs."""
        if self.phase is Phase.IDLE:
            return False
        self.phase = Phase.IDLE
        self.changes += 1
        self.watchdog.stop()
        return True

    # -- fault reset ------------------------------------------------------------------------
    def reset(self) -> bool:
        """Release the latched fault unless the task in progress is itself faulty.

        Returns True when released. A task still running after a fault that condemned it
        (``x - y`` never decreases within an attempt) keeps the fault: the monitor stays in
        step with the plant instead of pretending the late task is on time.
        """
        if self.latched is None:
            return True
        if self.running and self.attempt_fault is not None:
            return False
        self.latched = None
        self.changes += 1
        return True
