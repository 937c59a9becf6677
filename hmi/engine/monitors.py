"""Stopwatch monitors in the scan: one automaton per task, run after the output scan.

Why after the output scan: a monitor observes the I/O the scan exchanged with the plant, the
inputs read at t and the orders written at t. A task started by an order (`start: rise(d)`)
then starts at the very scan that sends the order, the instant the plant starts working, so
the stopwatches measure the plant's own durations (exactly, when the plant's events fall on
scan instants). A fault found at scan k is in snapshot k.

Composition (002 §4 composes the tasks into one 12-location automaton): here each task has
its own automaton, stepped independently at every scan. docs/monitors.md explains why the
detection instants are the same.

A monitor fault is a label, like a diagnoser's: latched until a fault reset, shown with the
stopwatch values at detection. It does not force outputs safe; the cell keeps working and the
operator decides.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

from hmi.engine.codegen import Vocabulary
from hmi.engine.layout import Layout
from hmi.engine.stopwatch import FAULTY, Detection, Phase, TaskAutomaton, WatchdogTrip, Window
from hmi.logic.expr import max_depth
from hmi.program import ir, order
from hmi.program.ir import Stmt
from hmi.program.monitors import lower_task
from hmi.project.model import Project, TaskMonitor
from hmi.project.monitors import monitors_of
from hmi.timefmt import format_duration, seconds

IDLE = Phase.IDLE
RUNNING = Phase.RUNNING


class MonitorState(NamedTuple):
    """One task's monitor at the end of a scan; immutable, for snapshots and traces.

    A named tuple rather than a frozen dataclass: one is built per task at every scan, and a
    tuple is several times cheaper to build.
    """

    name: str
    label: str
    title: str  # the task as the operator knows it
    device: str | None
    location: str  # waiting, executing, interrupted, faulty
    x_us: int  # time since the task started (kept running while faulty)
    y_us: int  # effective work (frozen while interrupted)
    alpha_us: int
    beta_us: int
    gamma_us: int
    attempt: int  # how many times the task started
    attempt_start_us: int
    running: bool  # the task is in progress (executing or interrupted), faulty or not
    detection: Detection | None  # the latched fault's evidence (None: label not raised)
    last_detection: Detection | None  # the most recent faulty attempt, latched or not
    watchdog: WatchdogTrip | None  # the last time a plain watchdog would have fired
    faults: int
    completed: int  # attempts that ended inside the acceptable window
    # what the task is doing as observed, a latched fault or not (waiting, executing,
    # interrupted): a faulty task halted with its load reads as stopped, not late
    phase: str = "waiting"

    @property
    def faulty(self) -> bool:
        return self.location == FAULTY

    @property
    def labels(self) -> tuple[str, ...]:
        return (self.label,) if self.faulty else ()


class MonitorStage:
    """The engine's stopwatch monitors: compiled conditions and one automaton per task.

    The states a snapshot shows are built lazily (:class:`LazyMonitors`): per task a *base*,
    the task's :class:`MonitorState` when it was last rebuilt and the time it was taken at,
    is kept; a running task whose automaton only advanced its stopwatches since (the
    compiled scan's common case, hmi.engine.compiled) is shown as its base with ``x`` and
    ``y`` moved on by the elapsed time, exactly what :meth:`TaskAutomaton.step` adds.
    """

    # each task's automaton, its watchdog and detection (hmi.program.monitors), and the
    # marks settled at the end of a scan (hmi.engine.program_stages.MONITORS)
    PRINTED = Vocabulary(
        frozenset({"phase", "x_us", "y_us", "last_us", "attempt", "attempt_start_us",
                   "attempt_fault", "changes", "completed", "watchdog", "_armed", "trip",
                   "detect", "settle"}),
        frozenset({"p", "x", "y", "el", "e", "verdict"}))

    def __init__(self, specs: tuple[TaskMonitor, ...], layout: Layout):
        self.specs = specs
        self.depth = max((max_depth(e) for s in specs for e in s.exprs), default=1)
        # The fields of MonitorState that never change, computed once (states() runs per scan).
        self.heads: list[tuple[str, str, str, str | None]] = [
            (s.name, s.label, s.title, s.device) for s in specs]
        self.tails = [(s.alpha_us, s.beta_us, s.gamma_us) for s in specs]
        self.automata = [TaskAutomaton(Window(s.alpha_us, s.beta_us, s.gamma_us))
                         for s in specs]
        # Per task: its base (see the class docstring) and whether TaskAutomaton.step ran on
        # it since the base was taken (then the base is taken again). A bytearray of 0 and 1,
        # not a list of bools: settle asks at every scan whether any is set, and ``True in``
        # a bytearray is one memchr where a list compares its items one by one (some 70
        # instructions each).
        self._bases: list[Base | None] = [None] * len(specs)
        self.dirty = bytearray([True] * len(specs))
        self.marks = 0  # the automata's changes, summed when a base is taken again
        # The bases, and the states when no task runs (None: built per scan, lazily).
        self._capture: tuple[tuple[Base, ...], tuple[MonitorState, ...] | None] | None = None
        # The tasks' automata at a scan, as the scan program (hmi.program.monitors): what
        # runs after the output scan (hmi.engine.compiled)
        programs: list[tuple[Stmt, ...]] = []
        for k, (spec, automaton) in enumerate(zip(specs, self.automata, strict=True)):
            start, end = ir.Test(spec.start.root), ir.Test(spec.end.root)
            suspend: ir.Value
            resume: ir.Value
            if spec.interrupted is not None:
                suspend = ir.Test(spec.interrupted.root)
                resume = ir.Not(suspend)
            elif spec.interrupt is not None and spec.resume is not None:
                suspend, resume = ir.Test(spec.interrupt.root), ir.Test(spec.resume.root)
            else:
                suspend = resume = ir.FALSE
            window = (spec.alpha_us, spec.beta_us, spec.gamma_us)
            mark = (ir.Assign(ir.Item(ir.Ref(self.dirty), k), ir.TRUE),)
            programs.append(lower_task(automaton, window, (Phase.IDLE, Phase.RUNNING,
                                                           Phase.SUSPENDED),
                                       start, end, suspend, resume, mark))
        self.programs = tuple(programs)  # per task (the PLC export prints one FB each)
        self.program = tuple(stmt for program in programs for stmt in program)

    @property
    def parts(self) -> Mapping[str, tuple[Stmt, ...]]:
        """Its statements, at the part of the scan after the output scan (a function of the
        scan program of its own: hmi.engine.compiled)."""
        return {order.MONITORS: self.program}

    def settle(self) -> int:
        """Take again the bases of the tasks stepped since (at the end of a scan); returns
        the marks (TaskAutomaton.changes summed)."""
        if self._capture is None or True in self.dirty:
            self._capture = self._rebase()
        return self.marks

    def capture(self, now: int) -> tuple[MonitorState, ...] | LazyMonitors:
        """The states at the end of the scan at `now`, for its snapshot: the states
        themselves when no task is running (the same tuple scan after scan), else a
        :class:`LazyMonitors` that builds them when read."""
        self.settle()
        assert self._capture is not None
        bases, idle = self._capture
        return idle if idle is not None else LazyMonitors(bases, now)

    def current(self, now: int) -> tuple[MonitorState, ...]:
        """Each task's state at the end of the scan at `now`."""
        states = self.capture(now)
        return states.states() if isinstance(states, LazyMonitors) else states

    def _rebase(self) -> tuple[tuple[Base, ...], tuple[MonitorState, ...] | None]:
        """Take again the base of every task stepped since its last one, and sum the
        automata's changes (TaskAutomaton.changes) in `marks`."""
        bases, dirty = self._bases, self.dirty
        running = False
        for k, (head, tail, a) in enumerate(zip(self.heads, self.tails, self.automata,
                                                strict=True)):
            base = bases[k]
            if dirty[k] or base is None:
                base = bases[k] = (_state(head, a, tail), a.last_us or 0, a.phase)
                dirty[k] = False
            running = running or base[2] is not IDLE
        marks = sum(a.changes for a in self.automata)
        if marks != self.marks:  # (unchanged, the very same object: compared by identity)
            self.marks = marks
        frozen: tuple[Base, ...] = tuple(bases)  # type: ignore[arg-type]  # every one is set
        return frozen, None if running else tuple(b[0] for b in frozen)

    def abandon(self) -> list[str]:
        """A recovery starts: every task in progress is forgotten (TaskAutomaton.abandon).
        Returns the tasks abandoned, by their titles."""
        abandoned = []
        for k, (spec, a) in enumerate(zip(self.specs, self.automata, strict=True)):
            if a.abandon():
                abandoned.append(spec.title)
                self.dirty[k] = True
        self._capture = None
        return abandoned

    def reset(self) -> list[str]:
        """Fault reset: release each latched label whose task is no longer faulty."""
        lines = []
        self.dirty[:] = [True] * len(self.automata)  # in place: the compiled scan holds it
        self._capture = None
        for spec, a in zip(self.specs, self.automata, strict=True):
            if a.latched is None:
                continue
            if a.reset():
                lines.append(f"{spec.label} released")
            else:
                lines.append(
                    f"{spec.label} stays: {spec.title} is still {a.phase.value} "
                    f"(x = {seconds(a.x_us)} s, y = {seconds(a.y_us)} s) and can no longer end "
                    f"before gamma {format_duration(spec.gamma_us)}; reset again once it ends")
        return lines


_X, _Y = MonitorState._fields.index("x_us"), MonitorState._fields.index("y_us")
assert _Y == _X + 1, "_at rebuilds MonitorState around x_us, y_us"

# A task's base: its state, when its automaton last advanced (TaskAutomaton.last_us), and
# its phase then.
Base = tuple[MonitorState, int, Phase]


class LazyMonitors:
    """The tasks' states at the end of one scan, built when first read (most snapshots of a
    headless run are never read for them). Immutable in meaning: the bases are frozen
    tuples and `now` the scan's time; :meth:`states` caches what it built."""

    __slots__ = ("_states", "bases", "now")

    def __init__(self, bases: tuple[Base, ...], now: int):
        self.bases = bases
        self.now = now
        self._states: tuple[MonitorState, ...] | None = None

    def states(self) -> tuple[MonitorState, ...]:
        states = self._states
        if states is None:
            states = self._states = tuple(_at(base, self.now) for base in self.bases)
        return states

    def __eq__(self, other: object) -> bool:
        if isinstance(other, LazyMonitors):
            other = other.states()
        return self.states() == other

    def __hash__(self) -> int:
        return hash(self.states())

    def __repr__(self) -> str:
        return repr(self.states())


def _at(base: Base, now: int) -> MonitorState:
    """A task's state at `now` from its base: a running task's stopwatches have advanced by
    the time elapsed since (``y`` only while executing), as TaskAutomaton.step advances them
    when nothing else happens."""
    state, since, phase = base
    if phase is IDLE or now == since:
        return state
    elapsed = now - since
    y = state.y_us + elapsed if phase is RUNNING else state.y_us
    # MonitorState._replace without its cost (a dict and a map per call)
    return tuple.__new__(MonitorState, (*state[:_X], state.x_us + elapsed, y, *state[_Y + 1:]))


def _state(head: tuple[str, str, str, str | None], a: TaskAutomaton,
           window: tuple[int, int, int]) -> MonitorState:
    return MonitorState(*head, a.location, a.x_us, a.y_us, *window, a.attempt,
                        a.attempt_start_us, a.running, a.latched, a.last_detection,
                        a.watchdog.last, a.faults, a.completed, a.phase.value)


def monitor_stage(project: Project, layout: Layout) -> MonitorStage | None:
    """The project's monitors as a scan stage (None for a project without monitors)."""
    specs = monitors_of(project)
    return MonitorStage(specs, layout) if specs else None
