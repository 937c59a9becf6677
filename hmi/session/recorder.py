"""What the UI remembers of every scan, not only of the scans it gets to draw.

The app draws at most ~20 times a second while the engine may scan every 10 ms, so reading
``session.last`` alone would miss short pulses: a one-scan edge, a 300 ms sensor glitch between
two frames. The recorder is called from the scan thread for every snapshot (through
``Session.scan_listeners``) and keeps, per Boolean signal, only its changes (time, value).
That costs a few comparisons per scan, and drawing a window of the chronogram is then
proportional to the number of changes in it, not to the number of scans.

It also keeps the plant's events (damage, glitches) which a snapshot carries only for the
scan in which they happened, and, per safety constraint, how often and when the filter found
it violated (a one-scan violation between two frames still counts).

The recorder runs where the scans run (the runtime). A screen elsewhere keeps a mirror of
it (:meth:`ScanRecorder.apply`), fed by what changed since the screen's last frame
(:meth:`ScanRecorder.since`): the same changes, events and constraint histories, so its
chronogram draws what one in the runtime's process would. Each scan's alarm transitions are
kept too (with the list as that scan left it), for a screen that must send every one of them
(the OPC UA gateway's condition events).

A frame must show one scan. The UI thread reads the recorder while the scan thread feeds it,
so the snapshot a frame shows and the history beside it are taken together, under the
recorder's lock (:meth:`ScanRecorder.latest`): reading ``session.last`` first and the history
a moment later mixed two scans — a constraint violated in the snapshot could be "not violated
now" in a history one scan newer (the HMI died of it on ``--control faulty``).
"""

from __future__ import annotations

import threading
from bisect import bisect_right
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from hmi.engine.layout import Layout
from hmi.explain.alarms import Alarm, AlarmEvent
from hmi.explain.model import Explanation
from hmi.plant.base import PlantEvent
from hmi.session.view import CellView

FOV_SUFFIX = ".fov"
KEEP_US = 120_000_000  # history kept: twice the chronogram's widest window


def _time(point: tuple[int, bool]) -> int:
    return point[0]


@dataclass(frozen=True)
class Signal:
    """A Boolean signal the chronogram can draw."""

    name: str  # as the project names it; "C.fov" for an output's functional value
    kind: str  # input, output, fov, timer, observer, memory, step
    slot: int  # index in Snapshot.values, or in Snapshot.fov for kind "fov"


def boolean_signals(layout: Layout) -> tuple[Signal, ...]:
    """Every Boolean signal of a layout, in the order an engineer reads a cell."""
    signals: list[Signal] = []
    for name in layout.outputs:
        signals.append(Signal(name, "output", layout.slots[name]))
    for name in layout.inputs:
        signals.append(Signal(name, "input", layout.slots[name]))
    for name in layout.timers:
        signals.append(Signal(name, "timer", layout.slots[name]))
    for name in layout.observers:
        signals.append(Signal(name, "observer", layout.slots[name]))
    for name in layout.memories:
        signals.append(Signal(name, "memory", layout.slots[name]))
    for name in layout.steps:
        signals.append(Signal(name, "step", layout.slots[name]))
    for index, name in enumerate(layout.outputs):
        signals.append(Signal(name + FOV_SUFFIX, "fov", index))
    return tuple(signals)


@dataclass(frozen=True)
class ConstraintStats:
    """A constraint's history: violation episodes (scans in a row), scans, last time."""

    name: str
    episodes: int = 0
    scans: int = 0
    since_us: int | None = None  # start of the current episode (None: not violated now)
    last_us: int | None = None  # last scan it was violated
    what: str | None = None  # the level-1 explanation last given during its last episode


@dataclass(frozen=True)
class Recorded:
    """The last scan recorded and the history as of that same scan (one consistent view)."""

    cell: CellView | None
    constraints: dict[str, ConstraintStats]
    damage_count: int


@dataclass(frozen=True)
class Cursor:
    """How far a screen's mirror has been told: the scan time, events and alarm batches."""

    time_us: int
    events: int
    batches: int


@dataclass(frozen=True)
class Changes:
    """What a recorder holds beyond a cursor, as of its last scan (a consistent view)."""

    cell: CellView | None
    full: bool  # everything kept (no cursor, or one older than what is kept)
    edges: tuple[tuple[int, int, bool], ...]  # (signal, time, value), in time order
    events: tuple[PlantEvent, ...]
    event_count: int
    damage_count: int
    constraints: dict[str, ConstraintStats]
    batches: tuple[tuple[tuple[AlarmEvent, ...], tuple[Alarm, ...]], ...]  # (events, list)
    batches_lost: int
    cursor: Cursor


@dataclass(frozen=True)
class Trace:
    """One signal over a window: its changes, and what was known before the window."""

    first_us: int | None  # time of the first sample recorded (None: nothing yet)
    initial: bool | None  # value at the window's start (None: before the first sample)
    changes: tuple[tuple[int, bool], ...]  # (time, new value) inside the window


class ScanRecorder:
    """Edges of every Boolean signal and the plant's events, fed from the scan thread."""

    def __init__(self, layout: Layout, keep_us: int = KEEP_US, keep_events: int = 500,
                 keep_batches: int = 2000):
        self.signals = boolean_signals(layout)
        self.by_name = {s.name: i for i, s in enumerate(self.signals)}
        self._value_slots = [(i, s.slot) for i, s in enumerate(self.signals) if s.kind != "fov"]
        self._fov_slots = [(i, s.slot) for i, s in enumerate(self.signals) if s.kind == "fov"]
        self._last: list[bool | None] = [None] * len(self.signals)
        # Per signal, its changes in time order; trimmed to `keep_us` of history (plus the
        # change before, which gives the level at the start of the oldest window).
        self._changes: list[list[tuple[int, bool]]] = [[] for _ in self.signals]
        self.keep_us = keep_us
        self._trim_at: int | None = None
        self.events: deque[PlantEvent] = deque(maxlen=keep_events)
        self.event_count = 0
        self.damage_count = 0
        self.scans = 0
        self.change_count = 0  # edges recorded so far: a cheap "anything new?" for drawing
        self._violated_now: set[str] = set()
        self._constraints: dict[str, ConstraintStats] = {}
        self.first_us: int | None = None
        self.last_us: int | None = None
        self.cell: CellView | None = None  # the last scan recorded
        # each scan's alarm transitions with the list it left (alarm events, alarms)
        self.batches: deque[tuple[tuple[AlarmEvent, ...], tuple[Alarm, ...]]] = deque(
            maxlen=keep_batches)
        self.batch_count = 0
        self._lock = threading.Lock()

    def on_scan(self, cell: CellView) -> None:
        """Called once per scan, in the scan thread: keep it cheap."""
        snap = cell.snapshot
        values, fov, last, changes = snap.values, snap.fov, self._last, self._changes
        t = snap.time_us
        with self._lock:
            for i, slot in self._value_slots:
                v = bool(values[slot])
                if v is not last[i]:
                    last[i] = v
                    changes[i].append((t, v))
                    self.change_count += 1
            for i, slot in self._fov_slots:
                v = bool(fov[slot])
                if v is not last[i]:
                    last[i] = v
                    changes[i].append((t, v))
                    self.change_count += 1
            if snap.plant_events:
                self.events.extend(snap.plant_events)
                self.event_count += len(snap.plant_events)
                self.damage_count += sum(1 for e in snap.plant_events if e.damage)
            report = snap.filter_report
            if report is not None and (report.violations or self._violated_now):
                self._count_violations(report.violated_names, t, cell.explanations)
            if cell.alarm_events:
                self.batches.append((cell.alarm_events, cell.alarms))
                self.batch_count += 1
            if self.first_us is None:
                self.first_us = t
                self._trim_at = t + self.keep_us
            elif self._trim_at is not None and t >= self._trim_at:
                self._trim(t - self.keep_us)
                self._trim_at = t + self.keep_us // 4
            self.last_us = t
            self.scans += 1
            self.cell = cell

    def _trim(self, before_us: int) -> None:
        """Forget changes older than `before_us`, keeping the last one before it."""
        self._trim_floor = before_us
        for points in self._changes:
            cut = bisect_right(points, before_us, key=_time) - 1
            if cut > 0:
                del points[:cut]

    def _count_violations(self, names: tuple[str, ...], t: int,
                          explanations: Sequence[Explanation] = ()) -> None:
        stats = self._constraints
        now = set(names)
        whats = {e.key: e.what for e in explanations
                 if e.key.startswith("constraint:")} if now else {}
        for name in now:
            old = stats.get(name) or ConstraintStats(name)
            new_episode = name not in self._violated_now
            what = whats.get(f"constraint:{name}") or (None if new_episode else old.what)
            stats[name] = ConstraintStats(
                name, old.episodes + new_episode, old.scans + 1,
                t if new_episode else old.since_us, t, what)
        for name in self._violated_now - now:
            old = stats[name]
            stats[name] = ConstraintStats(name, old.episodes, old.scans, None, old.last_us,
                                          old.what)
        self._violated_now = now

    def constraint_stats(self) -> dict[str, ConstraintStats]:
        with self._lock:
            return dict(self._constraints)

    def latest(self) -> Recorded:
        """The last snapshot recorded with the history as of it: what a frame shows."""
        with self._lock:
            return Recorded(self.cell, dict(self._constraints), self.damage_count)

    def trace(self, name: str, start_us: int, end_us: int) -> Trace:
        """The signal `name` between start and end (virtual time, inclusive of the end)."""
        index = self.by_name[name]
        with self._lock:
            points = self._changes[index]
            if not points:
                return Trace(None, None, ())
            before = bisect_right(points, start_us, key=_time)  # changes at or before start
            initial = points[before - 1][1] if before else None
            upto = bisect_right(points, end_us, key=_time)
            return Trace(points[0][0], initial, tuple(points[before:upto]))

    def recent_events(self, count: int = 20) -> list[PlantEvent]:
        with self._lock:
            return list(self.events)[-count:]

    # -- a mirror elsewhere -------------------------------------------------------------
    def since(self, cursor: Cursor | None) -> Changes:
        """Everything recorded after `cursor`, up to the last scan (its snapshot included);
        with no cursor, or one from before what is still kept, everything kept (`full`)."""
        with self._lock:
            cell = self.cell
            upto = cell.snapshot.time_us if cell is not None else -1
            full = cursor is None or (self.first_us is not None and self._trimmed_after(
                cursor.time_us))
            edges: list[tuple[int, int, bool]] = []
            for index, points in enumerate(self._changes):
                start = 0 if full or cursor is None else bisect_right(points, cursor.time_us,
                                                                      key=_time)
                edges.extend((index, t, v) for t, v in points[start:])
            edges.sort(key=lambda edge: edge[1])  # (a stable sort: signal order within a scan)
            told_events = 0 if full or cursor is None else cursor.events
            new_events = min(self.event_count - told_events, len(self.events))
            events = tuple(self.events)[len(self.events) - new_events:] if new_events else ()
            # (a first view starts from the alarm list as it is: no transitions from before)
            told_batches = self.batch_count if cursor is None else cursor.batches
            missing = self.batch_count - told_batches
            kept = min(missing, len(self.batches))
            batches = tuple(self.batches)[len(self.batches) - kept:] if kept else ()
            return Changes(cell, full, tuple(edges), events, self.event_count,
                           self.damage_count, dict(self._constraints), batches,
                           missing - kept, Cursor(upto, self.event_count, self.batch_count))

    def _trimmed_after(self, time_us: int) -> bool:
        """Whether changes after `time_us` may have been forgotten (trimmed): the oldest kept
        change of some signal is after it and is not the signal's first."""
        return self._trim_floor is not None and time_us < self._trim_floor

    _trim_floor: int | None = None  # changes before this time may be gone

    def apply(self, changes: Changes) -> None:
        """Take what another recorder recorded (:meth:`since`): this one then answers as
        that one does (a screen's mirror of the runtime's recorder)."""
        with self._lock:
            if changes.full:
                self._changes = [[] for _ in self.signals]
                self._last = [None] * len(self.signals)
                self.events.clear()
            for index, t, value in changes.edges:
                self._changes[index].append((t, value))
                self._last[index] = value
                self.change_count += 1
            self.events.extend(changes.events)
            self.event_count = changes.event_count
            self.damage_count = changes.damage_count
            self._constraints = dict(changes.constraints)
            self._violated_now = {name for name, stats in changes.constraints.items()
                                  if stats.since_us is not None}
            self.batches.extend(changes.batches)
            self.batch_count += len(changes.batches) + changes.batches_lost
            cell = changes.cell
            if cell is not None:
                t = cell.snapshot.time_us
                if self.first_us is None:
                    self.first_us = t
                    self._trim_at = t + self.keep_us
                elif self._trim_at is not None and t >= self._trim_at:
                    self._trim(t - self.keep_us)
                    self._trim_at = t + self.keep_us // 4
                self.last_us = t
                self.cell = cell
